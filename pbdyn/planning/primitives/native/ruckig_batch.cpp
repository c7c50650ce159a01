// Batched ruckig builds for pbdyn's motion-primitive planners, called from compiled (numba) code.
//
// pbdyn_ruckig_build computes n position-interface trajectories (current position 0, target acceleration 0; the
// other fields per candidate) with ruckig's own calculate(), the same library code the ruckig Python package wraps,
// and writes each trajectory's duration, result code and per-axis profiles in the layout of
// pbdyn/planning/ruckig_sampling.py (PROFILE_WIDTH = 49 doubles per axis). Built by pbdyn/planning/native/build.py
// against the sources of the installed ruckig version; pbdyn uses it only after checking it against the Python
// package bit for bit (pbdyn/planning/native/__init__.py).
#include <ruckig/ruckig.hpp>

#include <cstring>
#include <memory>

namespace {

constexpr long kWidth = 49;

// One calculator per axis count, with the axis count fixed at compile time (ruckig's arithmetic is the same for
// any DOFs; fixed sizes keep its vectors and the profile copy below off the heap).
template<size_t DOFs>
struct Builder {
    ruckig::Ruckig<DOFs> otg;
    ruckig::InputParameter<DOFs> input;
    ruckig::Trajectory<DOFs> trajectory;
};

thread_local std::unique_ptr<Builder<2>> builder2;
thread_local std::unique_ptr<Builder<3>> builder3;

void write_profile(const ruckig::Profile& p, double* out) {
    std::memcpy(out, p.t.data(), 7 * sizeof(double));
    std::memcpy(out + 7, p.j.data(), 7 * sizeof(double));
    std::memcpy(out + 14, p.p.data(), 8 * sizeof(double));
    std::memcpy(out + 22, p.v.data(), 8 * sizeof(double));
    std::memcpy(out + 30, p.a.data(), 8 * sizeof(double));
    const auto& b = p.brake;
    if (b.duration > 0.0) {
        out[38] = b.duration;
        std::memcpy(out + 39, b.t.data(), 2 * sizeof(double));
        std::memcpy(out + 41, b.j.data(), 2 * sizeof(double));
        std::memcpy(out + 43, b.p.data(), 2 * sizeof(double));
        std::memcpy(out + 45, b.v.data(), 2 * sizeof(double));
        std::memcpy(out + 47, b.a.data(), 2 * sizeof(double));
        if (!(b.t[1] > 0.0)) {
            // ruckig leaves the start state of an empty second brake phase unset (stale from an earlier
            // calculation); no sample reads it: zeros, so that equal trajectories give equal rows.
            out[44] = out[46] = out[48] = 0.0;
        }
    } else {
        std::memset(out + 38, 0, 11 * sizeof(double));
    }
}

template<size_t DOFs>
void build_all(Builder<DOFs>& b, long n, const double* cur_v, const double* cur_a, const double* tgt_p,
               const double* tgt_v, const double* lim_v, const double* lim_a, double jerk, double min_duration,
               double* profiles, double* durations, long* results) {
    constexpr long d = static_cast<long>(DOFs);
    auto& in = b.input;
    for (long i = 0; i < n; ++i) {
        for (long k = 0; k < d; ++k) {
            const long ik = i * d + k;
            in.current_position[k] = 0.0;
            in.current_velocity[k] = cur_v[ik];
            in.current_acceleration[k] = cur_a[ik];
            in.target_position[k] = tgt_p[ik];
            in.target_velocity[k] = tgt_v[ik];
            in.target_acceleration[k] = 0.0;
            in.max_velocity[k] = lim_v[i];
            in.max_acceleration[k] = lim_a[i];
            in.max_jerk[k] = jerk;
        }
        in.minimum_duration = min_duration;
        ruckig::Result r;
        try {
            r = b.otg.calculate(in, b.trajectory);
        } catch (...) {
            r = ruckig::Result::Error;
        }
        results[i] = static_cast<long>(r);
        durations[i] = b.trajectory.get_duration();
        if (r == ruckig::Result::Working || r == ruckig::Result::Finished) {
            const auto sections = b.trajectory.get_profiles();
            for (long k = 0; k < d; ++k) write_profile(sections[0][k], profiles + (i * d + k) * kWidth);
        }
    }
}

}  // namespace

extern "C" {

// The ruckig version this library was built from (its sources' version string).
const char* pbdyn_ruckig_version() { return PBDYN_RUCKIG_VERSION; }

// Build n trajectories with d axes (2 or 3). Inputs [n, d] row-major: current velocity and acceleration, target
// position and velocity; [n]: per-axis velocity and acceleration limits; scalars: the per-axis jerk limit and the
// minimum duration (s). Outputs: profiles [n, d, 49], durations [n] (s), ruckig result codes [n] (Working = 0 and
// Finished = 1 are successes; a rejected input gives its error code, an exception -1). Returns 0, or -1 for a d
// outside 2..3 (nothing written).
int pbdyn_ruckig_build(long n, long d, const double* cur_v, const double* cur_a, const double* tgt_p,
                       const double* tgt_v, const double* lim_v, const double* lim_a, double jerk,
                       double min_duration, double* profiles, double* durations, long* results) {
    if (d == 2) {
        if (!builder2) builder2 = std::make_unique<Builder<2>>();
        build_all(*builder2, n, cur_v, cur_a, tgt_p, tgt_v, lim_v, lim_a, jerk, min_duration, profiles, durations,
                  results);
        return 0;
    }
    if (d == 3) {
        if (!builder3) builder3 = std::make_unique<Builder<3>>();
        build_all(*builder3, n, cur_v, cur_a, tgt_p, tgt_v, lim_v, lim_a, jerk, min_duration, profiles, durations,
                  results);
        return 0;
    }
    return -1;
}

}  // extern "C"
