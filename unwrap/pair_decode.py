"""The traditional decode of one frequency pair on wrapped phases: the prior and the order the
learned unwrapping corrects (numpy only; used by the dataset reader and by inference, which must
not need torch)."""
from __future__ import annotations

import math

import numpy as np


def traditional(method: str, phi_lo, phi_hi, f_lo: float, f_hi: float, width: float, valid):
    """(prior float64 (H,W), order int64 (H,W) -1 invalid, valid bool) of one method on wrapped
    phases (rad), with unwrap's own decoders. ``order``: the method's order of the high
    frequency clipped to [0, round(f_hi)]."""
    from .temporal import mf_unwrap, mw_unwrap, nt_unwrap

    if method == "mf":
        r = mf_unwrap([phi_lo, phi_hi], (f_lo, f_hi), width=width, valid=valid)
        k = r.levels[-1][2]
    elif method == "mw":
        r = mw_unwrap([phi_lo, phi_hi], (f_lo, f_hi), width=width, valid=valid)
        k = r.levels[-1][2]
    else:
        r = nt_unwrap([phi_lo, phi_hi], (f_lo, f_hi), width=width, valid=valid)
        k = r.levels[1][2]
    prior = np.asarray(r.prior, dtype=np.float64)
    ok = valid & np.isfinite(prior)
    kmax = math.floor(f_hi + 0.5)
    order = np.where(ok, np.clip(np.nan_to_num(np.asarray(k, dtype=np.float64)), 0, kmax), -1).astype(np.int64)
    return np.where(ok, prior, 0.0), order, ok
