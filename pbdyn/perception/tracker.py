"""Batched constant-velocity Kalman tracks of dynamic obstacles (thesis 2-4-2, eq. 2-1..2-9).

One slot per obstacle: the obstacle index is the track id (data association is perfect). The state of a track is
[p, v] in R^{2d} (m, m/s, world frame). All tracks are filtered together with numpy on [N, 2d, 2d] arrays.
"""

from __future__ import annotations

import numpy as np

from pbdyn.config import TrackingConfig
from pbdyn.perception.tracks import Tracks


class KalmanTracks:
    """Kalman tracks of ``n_obstacles`` obstacles in ``dims`` dimensions with world step ``dt`` (s).

    Model (thesis eq. 2-6..2-9): A = [[I, dt I], [0, I]], H = [I, 0], Q = q I_2d, R = r I_d,
    P0 = diag(p0_pos I_d, p0_vel I_d). A track starts at its first detection with x = [z, 0], P = P0 (zero velocity:
    the thesis program's choice) and is not updated in that step. It is dropped when the largest position variance
    exceeds ``drop_pos_var`` (m^2) or its mean position leaves the arena box [bounds_lo, bounds_hi] (m); a dropped
    obstacle that is seen again starts a new track. R = 0 (the program's value) is allowed as long as q > 0 or
    the tracks' position covariance stays positive definite.

    ``drop_rule = "program"`` reproduces the thesis program's filter (its KalmanFilter.predict/update): a track is
    dropped right after its prediction, before the update, when its largest position variance reaches
    ``drop_pos_var`` or its predicted mean is not strictly inside the box shrunk by ``nominal_radius`` (the setup
    radius: the program's band 1 m + r from the border is r from its 1 m wall cells); that step's detection of it is
    discarded (the program fed it to the reset, inactive filter), the next detection starts a new track, and every
    track started after a drop carries ``nominal_radius`` instead of the obstacle's own radius (the program's reset
    set the setup radius). ``track_radius = "setup"``: every track reports ``nominal_radius`` (the program's planners
    when it flew the thesis' trials knew only the setup radius).
    """

    def __init__(self, n_obstacles: int, dims: int, dt: float, *, q: float = 1e-5, r: float = 0.0,
                 p0_pos: float = 0.01, p0_vel: float = 0.1, drop_pos_var: float = 1.5,
                 bounds_lo, bounds_hi, drop_rule: str = "arena", nominal_radius: float = 0.0,
                 track_radius: str = "own"):
        if dims not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {dims}")
        values = (dt, q, r, p0_pos, p0_vel, drop_pos_var)
        if not (n_obstacles >= 0 and dt > 0 and q >= 0 and r >= 0 and p0_pos > 0 and p0_vel >= 0
                and drop_pos_var > 0 and (q > 0 or r > 0) and all(np.isfinite(values))):
            raise ValueError("KalmanTracks needs n_obstacles >= 0, dt > 0, q >= 0, r >= 0, q + r > 0, p0_pos > 0, "
                             f"p0_vel >= 0, drop_pos_var > 0, all finite (got dt, q, r, p0_pos, p0_vel, drop_pos_var "
                             f"= {values})")
        if drop_rule not in TrackingConfig.DROP_RULES or not (np.isfinite(nominal_radius) and nominal_radius >= 0):
            raise ValueError(f"drop_rule must be one of {TrackingConfig.DROP_RULES} and nominal_radius finite >= 0, "
                             f"got {drop_rule!r}, {nominal_radius!r}")
        if track_radius not in TrackingConfig.TRACK_RADII:
            raise ValueError(f"track_radius must be one of {TrackingConfig.TRACK_RADII}, got {track_radius!r}")
        self.drop_rule = drop_rule
        self.track_radius = track_radius
        self.nominal_radius = float(nominal_radius)
        self.n = int(n_obstacles)
        self.dims = d = int(dims)
        self.dt = float(dt)
        self.drop_pos_var = float(drop_pos_var)
        self.bounds_lo = np.asarray(bounds_lo, dtype=float).reshape(d)
        self.bounds_hi = np.asarray(bounds_hi, dtype=float).reshape(d)
        eye = np.eye(d)
        self.A = np.block([[eye, self.dt * eye], [np.zeros((d, d)), eye]])
        self.Q = float(q) * np.eye(2 * d)
        self.R = float(r) * eye
        self.P0 = np.diag(np.r_[np.full(d, float(p0_pos)), np.full(d, float(p0_vel))])
        self.x = np.zeros((self.n, 2 * d))
        self.P = np.zeros((self.n, 2 * d, 2 * d))
        self.active = np.zeros(self.n, dtype=bool)
        self.ever = np.zeros(self.n, dtype=bool)
        self.restarted = np.zeros(self.n, dtype=bool)   # "program" rule: dropped at least once (nominal radius)
        self.tracked_time_s = 0.0

    @property
    def ever_tracked(self) -> int:
        """Number of obstacles that have ever had a track."""
        return int(np.count_nonzero(self.ever))

    @property
    def n_active(self) -> int:
        """Number of active tracks."""
        return int(np.count_nonzero(self.active))

    def predict(self) -> None:
        """Predict every active track one step ahead (eq. 2-1, 2-2; no control input)."""
        idx = np.flatnonzero(self.active)
        if idx.size:
            self._predict_at(self.x, self.P, (idx,))

    def update(self, ids, z) -> None:
        """Update seen active tracks with measured centres z [m, d] (m) of obstacles ``ids`` [m, unique] (eq. 2-3..2-5).

        Ids without an active track are initialised (x = [z, 0], P = P0) and not updated in this step. The covariance
        update uses the Joseph form of eq. 2-5 (algebraically equal for the optimal gain, keeps P symmetric).
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        z = np.asarray(z, dtype=float).reshape(ids.size, self.dims)
        if ids.size == 0:
            return
        self._check_ids(ids)
        self._update_at(self.x, self.P, self.active, self.ever, (ids,), z)

    def _check_ids(self, ids: np.ndarray) -> None:
        if np.any((ids < 0) | (ids >= self.n)):
            raise IndexError(f"track ids must be in [0, {self.n}), got {ids}")
        if np.unique(ids).size != ids.size:
            raise ValueError(f"track ids must be unique within one update, got {ids}")

    def drop(self) -> None:
        """Deactivate tracks whose largest position variance exceeds drop_pos_var or whose mean left the arena."""
        idx = np.flatnonzero(self.active)
        if idx.size:
            self.active[idx[self._gone_at(self.x, self.P, (idx,), predicted=False)]] = False

    def drop_predicted(self) -> np.ndarray:
        """"program" rule: deactivate the tracks whose predicted position variance reaches drop_pos_var or whose
        predicted mean is not strictly inside the box shrunk by nominal_radius; returns their ids."""
        idx = np.flatnonzero(self.active)
        if idx.size == 0:
            return idx
        gone = idx[self._gone_at(self.x, self.P, (idx,), predicted=True)]
        self.active[gone] = False
        self.restarted[gone] = True
        return gone

    # The filter's arithmetic on the tracks ``sel`` (a tuple of index arrays) of state arrays x [..., 2d] and
    # P [..., 2d, 2d]: this tracker's own (sel = (ids,)) or a TrackerBank's (sel = (rows, ids)).
    def _predict_at(self, x: np.ndarray, P: np.ndarray, sel: tuple) -> None:
        d = self.dims
        xs = x[sel]
        xs[:, :d] += self.dt * xs[:, d:]
        x[sel] = xs
        P[sel] = self.A @ P[sel] @ self.A.T + self.Q

    def _update_at(self, x: np.ndarray, P: np.ndarray, active: np.ndarray, ever: np.ndarray, sel: tuple,
                   z: np.ndarray) -> None:
        d = self.dims
        seen = active[sel]
        new = tuple(a[~seen] for a in sel)
        if new[0].size:
            x[new + (slice(None, d),)] = z[~seen]
            x[new + (slice(d, None),)] = 0.0
            P[new] = self.P0
            active[new] = True
            ever[new] = True
        upd = tuple(a[seen] for a in sel)
        if upd[0].size == 0:
            return
        xs = x[upd]
        Ps = P[upd]
        S = Ps[:, :d, :d] + self.R                                  # H P H^T + R
        K = np.linalg.solve(S, Ps[:, :d, :]).transpose(0, 2, 1)     # P H^T S^-1 (S, P symmetric)   [m, 2d, d]
        xs = xs + np.einsum("mij,mj->mi", K, z[seen] - xs[:, :d])
        IKH = np.broadcast_to(np.eye(2 * d), Ps.shape).copy()
        IKH[:, :, :d] -= K
        Ps = IKH @ Ps @ IKH.transpose(0, 2, 1) + K @ self.R @ K.transpose(0, 2, 1)
        x[upd] = xs
        P[upd] = Ps

    def _gone_at(self, x: np.ndarray, P: np.ndarray, sel: tuple, *, predicted: bool) -> np.ndarray:
        """Per selected track: True if it is dropped (drop(), or drop_predicted() when ``predicted``)."""
        d = self.dims
        pos_var = np.diagonal(P[sel + (slice(None, d), slice(None, d))], axis1=1, axis2=2).max(axis=1)
        pos = x[sel + (slice(None, d),)]
        if predicted:
            inside = np.all((pos > self.bounds_lo + self.nominal_radius)
                            & (pos < self.bounds_hi - self.nominal_radius), axis=1)
            return (pos_var >= self.drop_pos_var) | ~inside
        outside = np.any((pos < self.bounds_lo) | (pos > self.bounds_hi), axis=1)
        return (pos_var > self.drop_pos_var) | outside

    def step(self, ids, z) -> None:
        """One world step (docs/design.md step 3): predict, update with detections (ids [m], z [m, d]), drop ("program"
        rule: predict, drop, update; see the class doc).

        Adds dt per track still active afterwards to ``tracked_time_s``.
        """
        self.predict()
        if self.drop_rule == "program":
            gone = self.drop_predicted()
            if gone.size:
                ids = np.asarray(ids, dtype=np.int64).reshape(-1)
                keep = ~np.isin(ids, gone)
                ids, z = ids[keep], np.asarray(z, dtype=float).reshape(keep.size, self.dims)[keep]
            self.update(ids, z)
        else:
            self.update(ids, z)
            self.drop()
        self.tracked_time_s += self.dt * self.n_active

    def tracks(self, radii) -> Tracks:
        """The active tracks ordered by id, with obstacle radii taken from ``radii`` [N] (m) (track_radius = "setup":
        nominal_radius for every track; drop_rule = "program": for a restarted one)."""
        idx = np.flatnonzero(self.active)
        d = self.dims
        radii = np.asarray(radii, dtype=float).reshape(self.n)
        if self.track_radius == "setup":
            radii = np.full(self.n, self.nominal_radius)
        elif self.restarted.any():
            radii = np.where(self.restarted, self.nominal_radius, radii)
        return Tracks.of_owned(idx, self.x[idx, :d], self.x[idx, d:], self.P[idx], radii[idx])   # fresh copies

    def model(self) -> tuple:
        """What the filter's arithmetic depends on besides its state (trackers with equal models can share a
        TrackerBank)."""
        return (self.n, self.dims, self.dt, self.drop_pos_var, self.drop_rule, self.nominal_radius,
                self.bounds_lo.tobytes(), self.bounds_hi.tobytes(), self.A.tobytes(), self.Q.tobytes(),
                self.R.tobytes(), self.P0.tobytes())


class TrackIdError(ValueError):
    """Detections of a TrackerBank step named ids a tracker does not have (raised before any state changed)."""


class TrackerBank:
    """The state of up to ``capacity`` KalmanTracks of one model in shared arrays, so that the trackers of lockstep
    trials of a trial batch (pbdyn.sim.batch) step together: ``step`` does, for every tracker given, exactly what its own step()
    does -- the same float operations on every track (element-wise, or per track's matrices) -- in one array
    evaluation over all their tracks. An attached tracker keeps working on its own (its arrays are views into the
    bank's)."""

    def __init__(self, template: KalmanTracks, capacity: int):
        self.key = template.model()
        self.template = template
        n, d2 = template.n, 2 * template.dims
        self.x = np.zeros((capacity, n, d2))
        self.P = np.zeros((capacity, n, d2, d2))
        self.active = np.zeros((capacity, n), dtype=bool)
        self.ever = np.zeros((capacity, n), dtype=bool)
        self.restarted = np.zeros((capacity, n), dtype=bool)
        self.rows = 0
        self.free: list[int] = []          # rows given back (release) for later trackers

    def release(self, row: int) -> None:
        """Give ``row`` back for a tracker attached later (the tracker that held it must not be stepped again)."""
        self.free.append(row)

    def attach(self, tracker: KalmanTracks) -> int | None:
        """Move ``tracker``'s state into a free row of the bank (its arrays become views of it); the row, or None
        when the bank is full or the tracker's model differs."""
        if tracker.model() != self.key:
            return None
        if self.free:
            row = self.free.pop()
        elif self.rows < self.x.shape[0]:
            row = self.rows
            self.rows += 1
        else:
            return None
        for name in ("x", "P", "active", "ever", "restarted"):
            bank = getattr(self, name)
            bank[row] = getattr(tracker, name)
            setattr(tracker, name, bank[row])
        return row

    def step(self, rows: list[int], trackers: list[KalmanTracks], ids_list: list, z_list: list) -> None:
        """KalmanTracks.step(ids, z) of every tracker (attached at ``rows``) with its detections, together.
        Invalid ids (out of range, repeated within a tracker) raise TrackIdError before any state changes."""
        t = self.template
        d = t.dims
        rows_a = np.asarray(rows, dtype=np.intp)
        counts = [int(np.asarray(i).size) for i in ids_list]
        tt = np.repeat(rows_a, counts)
        nn = np.concatenate([np.asarray(i, dtype=np.int64).reshape(-1) for i in ids_list]) if tt.size else \
            np.zeros(0, np.int64)
        zz = np.concatenate([np.asarray(z, dtype=float).reshape(-1, d) for z in z_list]) if tt.size else \
            np.zeros((0, d))
        if nn.size and (np.any((nn < 0) | (nn >= t.n)) or np.unique(tt * t.n + nn).size != nn.size):
            raise TrackIdError("invalid track ids among the detections (step the trackers one by one to see whose)")
        ti, ni = np.nonzero(self.active[rows_a])
        ti = rows_a[ti]
        if ti.size:                                                             # predict (eq. 2-1, 2-2)
            t._predict_at(self.x, self.P, (ti, ni))
        if t.drop_rule == "program":
            if ti.size:
                gone = t._gone_at(self.x, self.P, (ti, ni), predicted=True)
                gt, gn = ti[gone], ni[gone]
                self.active[gt, gn] = False
                self.restarted[gt, gn] = True
                if nn.size and gt.size:                 # that step's detections of dropped tracks are discarded
                    dropped = np.zeros(self.active.shape, dtype=bool)
                    dropped[gt, gn] = True
                    keep = ~dropped[tt, nn]
                    tt, nn, zz = tt[keep], nn[keep], zz[keep]
            if nn.size:
                t._update_at(self.x, self.P, self.active, self.ever, (tt, nn), zz)
        else:
            if nn.size:
                t._update_at(self.x, self.P, self.active, self.ever, (tt, nn), zz)
            ti, ni = np.nonzero(self.active[rows_a])
            ti = rows_a[ti]
            if ti.size:
                bad = t._gone_at(self.x, self.P, (ti, ni), predicted=False)
                self.active[ti[bad], ni[bad]] = False
        n_active = np.count_nonzero(self.active[rows_a], axis=1).tolist()
        for tr, m in zip(trackers, n_active):
            tr.tracked_time_s += tr.dt * m

    def read_tracks(self, rows: list[int], radii_list: list) -> list[Tracks]:
        """KalmanTracks.tracks(radii) of the trackers attached at ``rows`` (radii_list: each one's obstacle radii
        [N], m), for all of them in one array evaluation: the same ids, means, velocities, covariances and radii,
        each tracker's Tracks holding read-only slices of shared fresh copies."""
        t = self.template
        d = t.dims
        rows_a = np.asarray(rows, dtype=np.intp)
        act = self.active[rows_a]
        ti, ni = (np.ascontiguousarray(i) for i in np.nonzero(act))     # (nonzero's are strided views)
        rr = rows_a[ti]
        if t.track_radius == "setup":
            radii = np.full(act.shape, t.nominal_radius)
        else:
            radii = np.stack([np.asarray(r, dtype=float).reshape(t.n) for r in radii_list])
            restarted = self.restarted[rows_a]
            if restarted.any():
                radii = np.where(restarted, t.nominal_radius, radii)
        pos, vel, cov, rad = self.x[rr, ni, :d], self.x[rr, ni, d:], self.P[rr, ni], radii[ti, ni]
        ends = np.cumsum(np.count_nonzero(act, axis=1)).tolist()
        out, lo = [], 0
        for hi in ends:
            out.append(Tracks.of_owned(ni[lo:hi], pos[lo:hi], vel[lo:hi], cov[lo:hi], rad[lo:hi]))
            lo = hi
        return out
