"""The record of one trial (thesis table 2-2, docs/design.md "Outcomes and the record")."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field


@dataclass(frozen=True)
class TrialResult:
    """One result row. Table 2-2 fields first; every timing field's name contains "wall".

    Units: times in s, distances in m, speeds in m/s; start/goal in m (world frame). planner_fingerprint: what
    code flew the trial (pbdyn.planning.registry.pair_fingerprint; "" where not recorded). profile: "physical" or
    "thesis_program" (docs/profiles.md "Profiles"). start_delay_s: the map time (s) at which the trial began (the start rule,
    pbdyn.sim.start; flight_time_s counts from it). max_speed_mps, max_accel_mps2: the largest executed |v| and
    acceleration (max of the samples' |a| and |v_k+1 - v_k| / dt); limits_exceeded: "" when both stayed within
    v_max and a_max, else which limit was exceeded and by how much (only possible under thesis_program).
    task_survivability_s, task_flux_per_s: the task's difficulty on the flown map from the trial's start
    (pbdyn.metrics.task: corridor survivability, s, higher = easier; corridor flux, 1/s, higher = harder); None
    where the corridor has no sample. path_length_m: the length of the flown path (sum of the executed steps'
    |p_k+1 - p_k|, m). wall_timings holds the wall-time splits (s), among them wall_planning_median_s and
    wall_planning_p99_s: the median and 99th percentile over the trial's steps of the planner's time per step.
    """

    gaze: str
    planner: str
    motion_profile: str
    map_index: int
    map_id: str
    map_seed: int
    obstacle_count: int
    obstacle_radius: float | dict
    obstacle_speed: float | dict
    mav_speed: float
    start: tuple[float, ...]
    goal: tuple[float, ...]
    flight_time_s: float
    grid_discovered: int
    obstacles_tracked: int
    tracked_time_s: float
    outcome: str
    final_state: str
    reason: str
    min_clearance_m: float
    planning_failures: int
    steps: int
    planner_label: str
    scenario: str
    map_key: str
    config_hash: str
    planner_fingerprint: str = ""
    profile: str = "physical"
    start_delay_s: float = 0.0
    max_speed_mps: float = 0.0
    max_accel_mps2: float = 0.0
    limits_exceeded: str = ""
    task_survivability_s: float | None = None
    task_flux_per_s: float | None = None
    path_length_m: float = 0.0
    wall_time_s: float = 0.0
    wall_timings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """A flat JSON-able dict (wall_timings entries become top-level keys)."""
        d = asdict(self)
        timings = d.pop("wall_timings")
        d["start"] = list(self.start)
        d["goal"] = list(self.goal)
        d.update(timings)
        return d

    def without_wall_times(self) -> dict:
        """to_dict() minus every field whose name contains "wall" (what determinism compares)."""
        return {k: v for k, v in self.to_dict().items() if "wall" not in k}
