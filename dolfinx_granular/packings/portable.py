"""Arithmetic of the packing generator that gives the same bits on every CPU and numpy release.

numpy's ``exp``, ``log`` and ``power`` dispatch on the CPU (numpy's own AVX-512 loops, Intel's
SVML, or the C library's, which itself picks FMA variants by CPU) and change between numpy
releases; the BLAS picks its kernels by CPU. Each rounds differently in the last bit, and the
jamming dynamics amplify any such bit into a different packing. The generator therefore uses
only what IEEE 754 rounds correctly, the same everywhere: +, -, *, / and sqrt (in numpy, and in
Numba, whose kernels are compiled without fastmath, so LLVM fuses no a * b + c into an FMA).
Its few other values come from here: logarithms and cube roots from Python's ``decimal``, whose
ln, exp and division are correctly rounded, so that a result is fixed by the arithmetic alone,
and sums from ``math.fsum`` (correctly rounded, so independent of the order and blocking).
"""

from __future__ import annotations

import decimal
import hashlib
import math
from decimal import Decimal

import numpy as np

#: significant digits of the decimal arithmetic (a float has 17)
DIGITS = 40


def context() -> decimal.Context:
    """A decimal context of :data:`DIGITS` digits, rounding half to even; its methods compute
    here, so that the caller's decimal context is left alone."""
    return decimal.Context(prec=DIGITS, rounding=decimal.ROUND_HALF_EVEN)


def ln(x: float) -> Decimal:
    """ln x of a float x > 0, correctly rounded to :data:`DIGITS` digits."""
    return context().ln(Decimal(float(x)))


def root(x: float, k: int) -> float:
    """x^(1/k) of a float x > 0, k = 2 or 3, the same float everywhere (sqrt is IEEE's; the cube
    root is exp(ln(x) / 3) in decimal, rounded once to a float)."""
    return math.sqrt(x) if k == 2 else _decimal_power(x, 1, k)


def inverse_roots(y: np.ndarray, k: int) -> np.ndarray:
    """y^(-1/k) of an array of floats > 0, k = 2 (1 / sqrt y) or 3 (exp(-ln(y) / 3) in decimal,
    ~40 µs a value)."""
    y = np.asarray(y, dtype=np.float64)
    if k == 2:
        return 1.0 / np.sqrt(y)
    return np.array([_decimal_power(v, -1, 3) for v in y.ravel().tolist()]).reshape(y.shape)


def inverse_power(x: float, k: int) -> Decimal:
    """x^-k of a float x > 0 and an integer k >= 1 in decimal (k - 1 products, one division)."""
    ctx = context()
    x = Decimal(float(x))
    p = x
    for _ in range(int(k) - 1):
        p = ctx.multiply(p, x)
    return ctx.divide(1, p)


def _decimal_power(x, num, den):
    """x^(num / den) of a float x > 0 as exp(num ln(x) / den) in decimal, rounded once to a
    float."""
    ctx = context()
    return float(ctx.exp(ctx.divide(ctx.multiply(ln(x), num), den)))


def total(values) -> float:
    """The correctly rounded sum of ``values`` (``math.fsum``: no order or blocking in it)."""
    return math.fsum(np.asarray(values, dtype=np.float64).ravel().tolist())


def mean(values) -> float:
    """The mean of ``values``: their correctly rounded sum over their count."""
    values = np.asarray(values, dtype=np.float64)
    return total(values) / values.size


def digest(*arrays) -> str:
    """sha256 (hex) of float arrays as little-endian float64 bytes, one after the other: a
    packing's ``digest(centers, radii, box)`` is the same on every machine that generates it."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
    return h.hexdigest()
