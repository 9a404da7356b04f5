"""The uncertainty a calibration reports, and the evidence beside it.

``assess_uncertainty(cal, obs, resample=...)`` gathers, for a joint calibration:

1. the adjustment's own standard deviations (independent residuals: ``cal.ba.std``);
2. the per-pose error model's (:mod:`calib.uncertainty.pose_error_model`): the reported uncertainty by default,
   since real sessions share errors within poses (where it cannot be computed, the adjustment's is
   reported and the reason is kept);
3. optionally a spread over resampled poses (:mod:`calib.uncertainty.resampling`, ``"jackknife"`` or
   ``"bootstrap"``), with a warning for every parameter where it and the reported sigma differ by
   more than ``DISAGREEMENT`` (1.5x) either way;
4. the residual diagnostics (:mod:`calib.uncertainty.diagnostics`) and the board warp estimate.

Every warning is logged (``calib`` logger) and kept in ``UncertaintyReport.warnings``; the report
goes into ``calibration.json`` under ``"uncertainty"`` and its table is printed by ``calib run``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..errors import UncertaintyError
from .level_uncertainty import MIN_DOF
from .pose_error_model import fit_pose_error_model
from .diagnostics import diagnose_residuals
from ..adjustment.jacobian import adjustment_jacobian

DISAGREEMENT = 1.5
RESAMPLING = ("none", "jackknife", "bootstrap")
MIN_WARP_VIEWS = 4
"""Views from which the board warp is estimated by default (fewer leave it too entangled with the
distortion terms to be worth its two parameters)."""

log = logging.getLogger(__name__)


@dataclass
class UncertaintyReport:
    """What :func:`assess_uncertainty` found (module docstring).

    - reported: "pose error model" or "independent residuals"; std: {name: 1-sigma reported};
      std_independent: the adjustment's; cov, cov_names: the reported covariance of the global
      parameters.
    - error_model: the :class:`calib.uncertainty.pose_error_model.PoseErrorModel` or None (why_not says why).
    - resampled: None or a :class:`calib.uncertainty.resampling.ResampledUncertainty`.
    - diagnostics: :class:`calib.uncertainty.diagnostics.ResidualDiagnostics`; warnings: [str].
    """

    reported: str
    std: dict
    std_independent: dict
    cov: np.ndarray
    cov_names: list
    error_model: object = None
    why_not: str | None = None
    resampled: object = None
    diagnostics: object = None
    warnings: list = field(default_factory=list)
    too_small: bool = False
    """True when the per-pose error levels rest on too few poses for the sigmas to be trusted
    (:mod:`calib.uncertainty.level_uncertainty`: a parameter's variance has < MIN_DOF effective degrees of freedom)."""

    def rows(self) -> list:
        """[(name, independent, reported, resampled or None, resampled / reported or None)]."""
        out = []
        for n, s in self.std.items():
            r = None if self.resampled is None else self.resampled.std.get(n)
            out.append((n, self.std_independent.get(n), s, r, None if r is None or not s else r / s))
        return out

    def to_dict(self) -> dict:
        d = {"reported": self.reported, "std": self.std, "std_independent": self.std_independent,
             "warnings": self.warnings, "diagnostics": None if self.diagnostics is None else self.diagnostics.to_dict()}
        if self.error_model is not None:
            em = self.error_model
            d["error_model"] = {"per_pose_field_sd_px": em.fields, "independent_fraction": em.independent_fraction,
                                "inflation": em.inflation()}
            if em.levels is not None:
                lv = em.levels
                d["error_model"]["few_poses"] = {
                    "sigma_inflation": dict(zip(em.names, lv.inflation.tolist())),
                    "effective_dof": {n: (None if not np.isfinite(v) else float(v)) for n, v in zip(em.names, lv.dof)},
                    "field_dof": lv.field_dof}
        elif self.why_not:
            d["error_model"] = {"not_computed": self.why_not}
        d["too_small_to_trust_sigmas"] = self.too_small
        if self.resampled is not None:
            rs = self.resampled
            d["resampled"] = {"method": rs.method, "std": rs.std, "runs": len(rs.runs), "failed": rs.failed,
                              "ratio_to_reported": {n: rs.std[n] / self.std[n] for n in rs.std
                                                    if self.std.get(n)}}
        return d


def warp_allowed(obs) -> tuple[bool, str]:
    """Whether the views allow estimating the board warp by default, and why."""
    n = sum(1 for v in obs.views if max(v.seen(d).sum() for d in v.q) >= 6) if obs.views else 0
    if n >= MIN_WARP_VIEWS:
        return True, f"{n} views (>= {MIN_WARP_VIEWS})"
    return False, f"only {n} views (the warp is estimated from {MIN_WARP_VIEWS})"


def _independent(cal):
    names = [n for n in cal.ba.std if "/" not in n]
    return names, {n: cal.ba.std[n] for n in names}


def assess_uncertainty(cal, obs, *, resample: str = "none", draws: int = 30, seed: int = 0) -> UncertaintyReport:
    """Uncertainty report of ``cal`` (a Calibration of ``obs``); see the module docstring."""
    if resample not in RESAMPLING:
        raise UncertaintyError(f"resample: expected one of {RESAMPLING}, got {resample!r}")
    names, independent = _independent(cal)
    em, why = None, None
    try:
        em = fit_pose_error_model(adjustment_jacobian(cal, obs), obs)
    except (UncertaintyError, np.linalg.LinAlgError) as exc:
        why = str(exc)
        log.info(f"per-pose error model not computed: {why}")
    if em is not None:
        report = UncertaintyReport("pose error model", dict(em.std), independent, em.cov, list(em.names), em)
    else:
        keep = [k for k, n in enumerate(cal.ba.free_names) if n in independent]
        cov = np.asarray(cal.ba.cov)[np.ix_(keep, keep)] if np.ndim(cal.ba.cov) == 2 else np.diag(
            [independent[n] ** 2 for n in names])
        report = UncertaintyReport("independent residuals", dict(independent), independent, cov,
                                   [cal.ba.free_names[k] for k in keep], None, why)
    report.diagnostics = diagnose_residuals(cal, obs)
    report.warnings += report.diagnostics.warnings
    if em is not None:
        worst = max(em.inflation().items(), key=lambda kv: kv[1])
        if worst[1] > DISAGREEMENT:
            report.warnings.append(_inflation_warning(em, worst))
        small = _too_small_warning(em, len(obs.views))
        if small:
            report.too_small = True
            report.warnings.append(small)
    if resample != "none":
        from .resampling import resample_poses

        log.info(f"{resample} over {len(obs.views)} poses")
        report.resampled = resample_poses(obs, cal.config, cal, resample, draws=draws, seed=seed)
        off = [(n, r) for n, _, _, _, r in report.rows() if r is not None and not 1 / DISAGREEMENT <= r <= DISAGREEMENT]
        if off:
            report.warnings.append(f"the {resample} spread and the reported sigma ({report.reported}) disagree by more "
                                   f"than {DISAGREEMENT}x for {len(off)} of {len(report.resampled.std)} parameters: "
                                   + ", ".join(f"{n} {r:.2f}x" for n, r in off[:6]) + (" ..." if len(off) > 6 else ""))
    for w in report.warnings[len(report.diagnostics.warnings):]:
        log.warning(w)
    return report


def _inflation_warning(em, worst) -> str:
    fields = sorted(em.fields.items(), key=lambda kv: -kv[1])[:3]
    return (f"residuals are shared within poses (per-pose error fields: "
            + ", ".join(f"{k} {v:.3f} px" for k, v in fields)
            + f"): the reported sigmas are up to {worst[1]:.1f}x the independent-residual ones ({worst[0]})")


def _too_small_warning(em, n_poses: int) -> str | None:
    """The warning for a session whose per-pose error levels rest on too few poses, or None."""
    if em.levels is None:
        return None
    dof = dict(zip(em.names, em.levels.dof))
    low = sorted((v, n) for n, v in dof.items() if v < MIN_DOF)
    if not low:
        return None
    infl = dict(zip(em.names, em.levels.inflation))
    return (f"this session ({n_poses} poses) is too small to trust its own sigmas: the per-pose error levels rest on "
            f"few poses (effective degrees of freedom {low[0][0]:.1f} for {low[0][1]}, below {MIN_DOF} for {len(low)} "
            f"of {len(dof)} parameters: those sigmas are uncertain by more than a third); they are inflated for it "
            f"(up to {max(infl.values()):.2f}x) but may still be off; add poses (docs/calib.md, 'Honest uncertainty')")


def uncertainty_table(report: UncertaintyReport, system_names=None) -> str:
    """Plain-text table: parameter, the adjustment's sigma, the reported one, the resampled spread."""
    rs = report.resampled
    head = f"{'parameter':<22}{'independent':>13}{'reported':>12}" + (f"{rs.method:>12}{'ratio':>8}" if rs else "")
    lines = [f"uncertainty (1 sigma): reported = {report.reported}", head]
    for n, ind, rep, res, ratio in report.rows():
        if system_names is not None and n not in system_names:
            continue
        line = f"{n:<22}{ind:>13.3g}{rep:>12.3g}"
        if rs:
            line += f"{res:>12.3g}{ratio:>8.2f}" if res is not None else f"{'':>12}{'':>8}"
        lines.append(line)
    if report.why_not:
        lines.append(f"(per-pose error model not computed: {report.why_not})")
    if report.too_small:
        lines.append("(too few poses to trust these sigmas: see the warning above)")
    return "\n".join(lines)
