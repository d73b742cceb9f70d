"""The paper's published figures (Mazza, Patel, Viola, TVCG 2020, Tables 1-3).

Measured on a 2016 MacBook Pro (2.9 GHz Intel Core i7) with a single-threaded Java
prototype, 100³ voxels rendered to 150² pixels. Seconds unless stated; Table 2 holds bytes
(the paper's MB are 10^6 bytes: 100³ · dims · 2 · bits / 8). The paper's render settings
(transfer functions, densities, sizes) are in :mod:`hevr.paper`.
"""

from __future__ import annotations

from ..paper import PAPER_SIZE

MACHINE = "2016 MacBook Pro, 2.9 GHz Intel Core i7, single-threaded Java prototype"

T1_BITS = (64, 128, 256, 512, 1024, 2048)
T3_BITS = (128, 256, 512, 1024, 2048)


def _row(*values: float) -> dict[int, float]:
    return dict(zip(T1_BITS, values))


def _row3(*values: float) -> dict[int, float]:
    return dict(zip(T3_BITS, values))


# Table 1: TABLE1[sampling][obfuscated][stage][bits]; PLAIN1[sampling] = plaintext render.
TABLE1 = {
    "nearest": {
        False: {
            "encrypt": _row(0.46, 0.48, 0.54, 0.56, 0.62, 0.57),
            "render": _row(0.54, 0.66, 0.89, 1.61, 3.49, 9.49),
            "decrypt": _row(0.17, 0.25, 0.63, 2.56, 14.92, 99.56),
        },
        True: {
            "encrypt": _row(5.72, 15.36, 59.54, 327.24, 2256.01, 16880.00),
            "render": _row(1.10, 1.77, 4.18, 11.61, 37.10, 94.30),
            "decrypt": _row(0.21, 0.43, 1.36, 4.94, 27.24, 185.94),
        },
    },
    "trilinear": {
        False: {
            "encrypt": _row(0.46, 0.47, 0.52, 0.57, 0.54, 0.65),
            "render": _row(10.59, 13.55, 21.38, 47.25, 146.07, 487.58),
            "decrypt": _row(0.14, 0.26, 0.64, 2.59, 14.65, 100.72),
        },
        True: {
            "encrypt": _row(5.82, 14.67, 59.93, 330.56, 2226.01, 16512.47),
            "render": _row(16.67, 23.86, 47.07, 121.05, 385.71, 1182.48),
            "decrypt": _row(0.20, 0.41, 1.20, 4.89, 26.86, 186.38),
        },
    },
}
PLAIN1 = {"nearest": 0.03, "trilinear": 0.08}

# Table 2: bytes per channel count (1 = scalar) and key size; plain is 8-bit.
TABLE2 = {dims: {bits: PAPER_SIZE**3 * dims * 2 * bits // 8 for bits in T1_BITS} for dims in (1, 2, 3, 4)}

# Table 3: encrypt per encoding; render / decrypt per (encoding, colours).
TABLE3_ENCRYPT = {
    2: _row3(29.87, 115.03, 622.77, 4405.69, 31796.00),
    3: _row3(40.30, 162.22, 897.28, 6271.48, 47030.98),
    4: _row3(54.97, 213.21, 1199.68, 8512.23, 62959.05),
}
TABLE3_RENDER = {
    (2, 1): _row3(21.85, 48.59, 142.36, 544.35, 1999.51),
    (2, 2): _row3(23.38, 58.20, 131.10, 659.48, 2716.51),
    (3, 1): _row3(19.59, 40.21, 143.69, 560.98, 2299.65),
    (3, 2): _row3(25.87, 56.24, 154.71, 770.64, 2850.69),
    (3, 3): _row3(41.67, 89.73, 257.51, 919.41, 3685.33),
    (4, 1): _row3(19.46, 42.93, 98.08, 429.30, 2292.48),
    (4, 2): _row3(35.41, 61.60, 179.45, 729.11, 3234.38),
    (4, 3): _row3(46.41, 93.63, 268.59, 1045.56, 4251.69),
    (4, 4): _row3(63.57, 123.32, 343.20, 1320.86, 5217.38),
}
TABLE3_DECRYPT = {
    (2, 1): _row3(0.80, 1.37, 4.95, 27.7, 180.40),
    (2, 2): _row3(0.33, 1.18, 3.23, 27.09, 187.51),
    (3, 1): _row3(0.53, 0.83, 4.47, 25.98, 127.84),
    (3, 2): _row3(0.43, 0.80, 3.18, 27.67, 120.99),
    (3, 3): _row3(0.59, 1.21, 4.83, 25.46, 181.86),
    (4, 1): _row3(0.28, 0.77, 1.54, 8.50, 60.03),
    (4, 2): _row3(0.46, 0.76, 3.10, 18.36, 121.76),
    (4, 3): _row3(0.45, 1.11, 4.52, 26.15, 190.63),
    (4, 4): _row3(0.67, 1.51, 4.68, 26.82, 190.49),
}
PLAIN3 = {
    (2, 1): 0.05,
    (2, 2): 0.06,
    (3, 1): 0.05,
    (3, 2): 0.06,
    (3, 3): 0.06,
    (4, 1): 0.06,
    (4, 2): 0.07,
    (4, 3): 0.07,
    (4, 4): 0.08,
}
