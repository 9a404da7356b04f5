"""The paper's tables S5 and S6 (fringe-order error rates, percent), for side-by-side reports.

Liu et al., "Digital-Twin-Driven Unambiguous Structured Light 3D Imaging with Physics-Aware
Learning", supplementary information, sections 4-5, tables S5 and S6, as transcribed in
shared/reference/seed_tables.json. DP-TPU MW at f = 48 is printed '1.0"%' in the table; the
text says 1.07 %.
"""
METHODS = ("MF", "MW", "NT")

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
