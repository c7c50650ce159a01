"""pbdyn: a PyBullet testbed for MAV dynamic obstacle avoidance and environment difficulty.

The public Python API (pbdyn.api, docs/api.md): load_scenario, rollout, run_trial, compute_metrics,
run_batch, merge_results, open_results, generate_maps, check_planner; the errors they raise (ConfigError, PbdynError) and the
warning they give (PbdynWarning); TrialResult and Outcome.
Names are imported on first use, so ``import pbdyn`` stays fast.
"""

__version__ = "0.1.0"

_API = ("load_scenario", "map_info", "rollout", "run_trial", "compute_metrics", "metric_heatmaps", "metric_backend", "run_batch", "merge_results",
        "replay", "open_results", "generate_maps", "calibrate", "bench", "compare_cards",
        "Results", "export_results", "evaluate", "check_planner", "run_demo")
_OTHER = {"ConfigError": "pbdyn.errors", "PbdynError": "pbdyn.errors", "PbdynWarning": "pbdyn.errors",
          "TrialResult": "pbdyn.sim.result",
          "Outcome": "pbdyn.outcome", "Scenario": "pbdyn.config"}

__all__ = ["__version__", *_API, *_OTHER]


def __getattr__(name: str):
    import importlib

    if name in _API:
        return getattr(importlib.import_module("pbdyn.api"), name)
    if name in _OTHER:
        return getattr(importlib.import_module(_OTHER[name]), name)
    raise AttributeError(f"module 'pbdyn' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
