"""Every number the toolkit takes from the paper's printed pages, in one place.

Source: Liu et al., "Digital-Twin-Driven Unambiguous Structured Light 3D Imaging with
Physics-Aware Learning", supplementary information (tables S2-S4, eqs. S1-S3) and Fig. 3 (its
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
