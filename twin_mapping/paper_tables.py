"""Every number the toolkit takes from the paper's printed pages, in one place.

Source: Liu et al., "Digital-Twin-Driven Unambiguous Structured Light 3D Imaging with
Physics-Aware Learning", supplementary information (tables S2-S6, eqs. S1-S3) and Fig. 3 (its
sphere-fit RMS values, also in the dp-tpu README), as transcribed in
``shared/reference/seed_tables.json``. Printed values are rounded and not always consistent
(:mod:`twin_mapping.paper` says where); compare against them, never compute from them.
"""

#: Table S3 as printed (degrees, mm), strings to keep the printed decimals.
TABLE_S3 = {
    "camera": {"rotation_euler_deg": ["4.4822", "7.8134", "-0.3567"],
               "location_mm": ["10.1985", "-93.2745", "835.7891"]},
    "projector": {"rotation_euler_deg": ["4.3868", "-1.0881", "-1.8107"],
                  "location_mm": ["-20.8421", "-86.2501", "797.1710"]},
}
#: Eqs. S1-S3 as printed: focal lengths in mm, and the projector pixel pitch of eq. S2 (um).
EQ_S1_S3 = {"camera": {"focal_length_mm": ["12.4423", "12.4449"]},
            "projector": {"focal_length_mm": ["20.5089"], "pixel_pitch_um": ["11.84", "6.64"]}}
#: Table S2 rotations as printed (rows).
TABLE_S2_ROTATIONS = {
    "camera": [[0.990, -0.006, -0.135], [-0.016, -0.996, -0.0774], [0.135, 0.079, -0.987]],
    "projector": [[0.999, -0.031, 0.019], [-0.030, -0.996, -0.076], [0.021, 0.075, -0.996]],
}

#: Table S2 (the real system): intrinsics (px), skew and translation (mm), as printed.
TABLE_S2 = {
    "camera": {"fx": 2592.156, "fy": 2592.696, "cx": 309.047, "cy": 236.166, "skew": -0.2332,
               "t": [4.866, -26.432, 847.611]},
    "projector": {"fx": 1732.166, "fy": 3463.328, "cx": 443.108, "cy": 588.109, "skew": -0.9514,
                  "t": [2.963, -25.620, 801.679]},
}
#: Table S4 (the calibration inside the twin): intrinsics (px), skew and translation (mm), as printed.
TABLE_S4 = {
    "camera": {"fx": 2601.299, "fy": 2601.946, "cx": 310.331, "cy": 241.586, "skew": -0.2568,
               "t": [4.281, -25.448, 845.854]},
    "projector": {"fx": 1730.956, "fy": 3435.8350, "cx": 437.855, "cy": 559.994, "skew": 0.0144,
                  "t": [2.405, -27.955, 800.933]},
}
#: Fig. 3: sphere-fit RMS (um) of the standard ball, (phase, calibration) -> value; the paper's
#: linear triangulation with K[R|T] of pose 1, no distortion, least-squares sphere fit.
FIG3_SPHERE_RMS_UM = {("real", "real"): 58.541, ("real", "twin"): 61.999, ("twin", "real"): 32.125,
                      ("twin", "twin"): 28.256}

# Tables S5 and S6 (sections 4-5): fringe-order error rates, percent. DP-TPU MW at f = 48 is
# printed '1.0"%' in the table; the text says 1.07 %.

#: S5: {frequency: {row: (MF, MW, NT)}}; 48 seen in training, 96 unseen.
TABLE_S5 = {
    48: {"Traditional": (3.39, 4.12, 3.73), "DT-TPU": (2.37, 2.63, 2.46), "UNet-TPU": (1.51, 1.68, 1.59),
         "DP-TPU": (0.97, 1.07, 1.01)},
    96: {"Traditional": (11.40, 15.01, 12.14), "DT-TPU": (100.0, 100.0, 100.0), "UNet-TPU": (100.0, 100.0, 100.0),
         "DP-TPU": (3.04, 4.99, 4.63)},
}

#: S6: {frequency: {method: (MSE, MSE + FL)}}.
TABLE_S6 = {
    16: {"MF": (0.11, 0.10), "MW": (0.22, 0.20), "NT": (0.16, 0.15)},
    32: {"MF": (0.33, 0.32), "MW": (0.72, 0.71), "NT": (0.51, 0.51)},
    48: {"MF": (0.68, 0.66), "MW": (0.83, 0.79), "NT": (0.70, 0.69)},
    64: {"MF": (1.41, 1.35), "MW": (1.90, 1.85), "NT": (1.59, 1.53)},
    80: {"MF": (2.16, 2.07), "MW": (2.62, 2.57), "NT": (2.44, 2.35)},
    96: {"MF": (3.08, 2.98), "MW": (5.05, 4.64), "NT": (4.92, 4.46)},
}
