"""The constants of the fused MF kernel's float64 arithmetic, shared by its three implementations
(numba :mod:`unwrap._fused_kernel`, C :mod:`unwrap._fused_c`, numpy :mod:`unwrap._fused_numpy`), so
that they cannot drift apart.

``R``: atan(u) = u + u z R(z), z = u^2, |u| <= tan(pi/8); R is the degree-10 polynomial
interpolating (atan(u)/u - 1)/z at 11 Chebyshev nodes of [0, tan(pi/8)^2], computed with mpmath
at 50 digits (max |error| of atan 5.6e-17 rad on the interval, below half an ulp of tan(pi/8)).
"""
import math

R = (-0.3333333333333333, 0.1999999999999552, -0.14285714284666542, 0.11111111015256361,
     -0.09090904578123903, 0.07692183190826087, -0.06664511447381948, 0.0585814891280221,
     -0.0508544973794026, 0.03923165829558719, -0.01917688711906226)
TAN_PI_8 = 0.41421356237309503
PI = math.pi
PI_2 = 0.5 * math.pi
PI_4 = 0.25 * math.pi
PI_4_LO = 3.061616997868383e-17  # pi/4 - float(pi/4)
TWO_PI = 2.0 * math.pi
HALF_TIE = 0.5 + 1e-9  # unwrap._xp.round_order: ceil(prior - 1/2 - TIE_BAND), ties down
BLOCK = 4096  # pixels per block (measured: 2048-8192 within noise, 512 is 20 % slower)
