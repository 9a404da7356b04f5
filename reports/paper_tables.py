"""The paper's printed table S4 (calibration inside the twin), for the report's side-by-side view.

Liu et al., supplementary information, table S4, as transcribed in shared/reference/seed_tables.json.
"""
TABLE_S4 = {
    "camera": {"fx": 2601.299, "fy": 2601.946, "cx": 310.331, "cy": 241.586, "skew": -0.2568,
               "t": [4.281, -25.448, 845.854]},
    "projector": {"fx": 1730.956, "fy": 3435.8350, "cx": 437.855, "cy": 559.994, "skew": 0.0144,
                  "t": [2.405, -27.955, 800.933]},
}
TABLE_S2 = {
    "camera": {"fx": 2592.156, "fy": 2592.696, "cx": 309.047, "cy": 236.166, "skew": -0.2332,
               "t": [4.866, -26.432, 847.611]},
    "projector": {"fx": 1732.166, "fy": 3463.328, "cx": 443.108, "cy": 588.109, "skew": -0.9514,
                  "t": [2.963, -25.620, 801.679]},
}
