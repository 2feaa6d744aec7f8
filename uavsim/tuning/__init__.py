"""Tuning rule, relative sensitivity J, (beta, pm) search and the class grids.

    from uavsim.tuning import TuningRule, load_grid
    g = TuningRule(beta=-0.73, pm_deg=20).gains(p)
    grid = load_grid("altitude"); grid.kp, grid.J
"""

from uavsim.tuning.rule import DEFAULT_BETA, DEFAULT_PM_DEG, Gains, TuningRule, rule_constants

__all__ = ["DEFAULT_BETA", "DEFAULT_PM_DEG", "Gains", "TuningRule", "rule_constants", "load_grid", "Grid"]


def __getattr__(name):  # lazy: grid imports are heavier
    if name in ("load_grid", "Grid"):
        from uavsim.tuning import grid

        return getattr(grid, name)
    raise AttributeError(name)
