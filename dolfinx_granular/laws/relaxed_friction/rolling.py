"""Rolling resistance of one contact of the relaxed cell: a rolling spring with a cap (Iwashita &
Oda 1998; the elastic-plastic spring of LIGGGHTS' ``epsd2`` rolling model, without its dashpot in
statics).

The relative rotation of the two disks over an increment,

    rho = (theta_i - theta_0i) - (theta_j - theta_0j),

(zero for a rigid turn of the pair: objective) loads a spring k_r = beta k_t r_eff^2,
r_eff = r_i r_j / (r_i + r_j), from the committed rolling moment m_0. The trial moment
m* = m_0 + k_r rho sticks where |m*| <= mu_r r_eff f_n (f_n = k_n e), else it slips on the cap,
m = mu_r r_eff f_n sign(m*) (backward Euler, as the sliding spring's return map). In stick the
contact stores m*^2 / (2 k_r); its generalised moments are dW/dtheta_i = m, dW/dtheta_j = -m:
disk i feels the couple -m, disk j +m. A couple moves no centre, so the rolling moments do not
enter the stress P (and the Cauchy stress stays symmetric at equilibrium: they cancel in the sum
of the moments). With u = (w_i, theta_i, w_j, theta_j) and a = d rho/du = (0, 0, 1, 0, 0, -1):

    d r/du += a (x) dm,   dm = k_r a (stick),  sign(m*) mu_r r_eff k_n de/du (slip),

the latter also with respect to F (through e): not symmetric in slip, as sliding is not.
mu_r = 0 gives no rolling spring at all (status OPEN: the law without it, bit for bit).
"""

from __future__ import annotations

from numba import njit

OPEN, STICK, SLIP = 0, 1, 2


@njit(cache=True, inline="always")
def radius(ri, rj):
    """r_eff = r_i r_j / (r_i + r_j), the lever of the rolling moment's cap and stiffness."""
    return ri * rj / (ri + rj)


@njit(cache=True)
def rolling_map(th, th0, m0, i, j, ri, rj, e, kn, kr, mu_r):
    """``(m, m*, status)`` of one contact with overlap e > 0 (committed moment m0, N m per unit
    thickness; ``kr`` = beta k_t, N/m²)."""
    if mu_r == 0.0:
        return 0.0, 0.0, OPEN
    reff = radius(ri, rj)
    rho = (th[i] - th0[i]) - (th[j] - th0[j])
    ms = m0 + kr * reff * reff * rho
    cap = mu_r * reff * kn * e
    if abs(ms) <= cap:
        return ms, ms, STICK
    return (cap if ms >= 0.0 else -cap), ms, SLIP


@njit(cache=True)
def add_rolling(m, status, ri, rj, kn, kr, mu_r, de, deF, tangent, out):
    """Add one contact's rolling moment to its generalised forces ``out[0]`` (6,) and, by
    ``tangent`` (1: Kuu ``out[2]``; 2: KuF ``out[5]`` too), its derivatives (``de``, ``deF``:
    de/du (6,), de/dF (4,), :func:`~dolfinx_granular.laws.relaxed_friction.contact_law.local`'s)."""
    if status == OPEN:
        return
    r = out[0]
    r[2] += m
    r[5] -= m
    if tangent == 0:
        return
    add_jacobian(m, status, ri, rj, kn, kr, mu_r, de, out[2])
    if tangent == 2:
        add_mixed(m, status, ri, rj, kn, mu_r, deF, out[5])


@njit(cache=True, inline="always")
def add_mixed(m, status, ri, rj, kn, mu_r, deF, KuF):
    """Add the rolling moment's dr/dF to one contact's KuF (6, 4) (deF: de/dF (4,)): only a
    slipping spring's cap moves with F."""
    if status == SLIP:
        reff = radius(ri, rj)
        k = mu_r * reff * kn if m >= 0.0 else -mu_r * reff * kn
        for p in range(4):
            KuF[2, p] += k * deF[p]
            KuF[5, p] -= k * deF[p]


@njit(cache=True, inline="always")
def add_jacobian(m, status, ri, rj, kn, kr, mu_r, de, Kuu):
    """Add the rolling moment's dr/du to one contact's Kuu (6, 6) (status STICK or SLIP; de:
    de/du (6,))."""
    reff = radius(ri, rj)
    if status == STICK:
        k = kr * reff * reff
        Kuu[2, 2] += k
        Kuu[2, 5] -= k
        Kuu[5, 2] -= k
        Kuu[5, 5] += k
        return
    k = mu_r * reff * kn if m >= 0.0 else -mu_r * reff * kn
    for v in range(6):
        Kuu[2, v] += k * de[v]
        Kuu[5, v] -= k * de[v]


@njit(cache=True)
def stiffness(ri, rj, kr):
    """The contact's rolling stiffness k_r = kr r_eff^2 (N m per rad per unit thickness)."""
    reff = radius(ri, rj)
    return kr * reff * reff
