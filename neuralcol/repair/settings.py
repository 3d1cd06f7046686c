"""Settings of the exact repairs (``handler.repair`` in ``conf/handler/default.yaml``): which repairs run, their
separation, steps and caps, and the one reading of a run's config."""

from __future__ import annotations

from dataclasses import dataclass, field

REPAIR_METHODS = ("contact", "untangle", "contact_untangle")


@dataclass(frozen=True)
class RepairSettings:
    """Settings of the contact repair (``handler.repair`` in ``conf/handler/default.yaml``)."""

    enabled: bool = True
    delta: float = 3.0          # separation asked for per intersecting pair, in the labeler's eps
    smooth_steps: int = 16      # diffusion steps the push is spread by
    max_smooth: int | None = None  # grow the diffusion up to this when stalled (None: fixed)
    max_iter: int = 60
    max_step: float = 0.002     # no vertex moves more than this fraction of the diagonal per iteration
    first: bool = True          # resolve: repair the input first, the neural handler only for what it leaves
    method: str = "contact_untangle"  # contact: the contact push (repair.contact); untangle: region push + contour
                                # minimisation; contact_untangle (default, rule v2): the push, and untangle
                                # (from the input) where it fails
    untangle: dict | None = None  # settings of neuralcol.repair.untangle.UntangleSettings (None: its defaults)
    retry: dict | None = field(default_factory=lambda: {"anchor": 0.01})  # untangle settings changed for a third
    # attempt, from the input, where the repairs above leave a mesh colliding; kept only where it frees it (None: no
    # third attempt). Default: a wider field (docs/studies/wider_untangle.md)
    shrink_steps: int = 0       # resolve: bisection steps shrinking the neural path's correction (0: off)
    cap_steps: int = 6          # resolve: bisection steps capping a freed result's displacement (0: off; the
                                # default, rule v10 met)

    def __post_init__(self):
        if self.delta <= 0 or self.smooth_steps < 0 or self.max_iter < 0 or self.max_step <= 0:
            raise ValueError(f"handler.repair {self}: need delta > 0, smooth_steps >= 0, max_iter >= 0, "
                             "max_step > 0")
        for key in ("shrink_steps", "cap_steps"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"handler.repair.{key}={value!r}; use 0 (off) or a whole number of steps")
        if self.method not in REPAIR_METHODS:
            raise ValueError(f"handler.repair.method={self.method!r}; use one of {', '.join(REPAIR_METHODS)}")
        if self.retry is not None:
            from neuralcol.repair.untangle import UntangleSettings

            known = set(UntangleSettings.__dataclass_fields__)
            if not isinstance(self.retry, dict) or set(self.retry) - known:
                raise ValueError(f"handler.repair.retry={self.retry!r}; give null or untangle settings to change "
                                 f"(keys of {sorted(known)})")


def repair_settings(cfg) -> RepairSettings | None:
    """:class:`RepairSettings` from a ``handler.repair`` mapping (None or ``enabled: false``: no repair)."""
    if cfg is None:
        return None
    c = dict(cfg)
    unknown = set(c) - set(RepairSettings.__dataclass_fields__)
    if unknown:
        raise ValueError(f"handler.repair: unknown keys {sorted(unknown)}; known: "
                         f"{sorted(RepairSettings.__dataclass_fields__)}")
    s = RepairSettings(**c)
    return s if s.enabled else None


def repair_from_config(cfg, enabled: bool | None = None, overrides=()) -> RepairSettings | None:
    """The contact repair a run's config asks for: its ``handler.repair`` (a run older than the repair has none:
    off), with ``key=value`` ``overrides`` and ``enabled`` forcing it on or off; None when off. The one reading of
    the setting (``experiments.run``, :meth:`neuralcol.api.TrainedRun.resolve`, ``experiments.evaluate_realistic``).
    """
    from omegaconf import OmegaConf

    node = OmegaConf.select(cfg, "handler.repair")
    base = OmegaConf.create({"enabled": False} if node is None else OmegaConf.to_container(node, resolve=True))
    c = OmegaConf.to_container(OmegaConf.merge(base, OmegaConf.from_dotlist(list(overrides))), resolve=True)
    if enabled is not None:
        c["enabled"] = bool(enabled)
    return repair_settings(c)
