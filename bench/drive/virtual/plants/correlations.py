"""Heat-transfer correlations and fluid properties of the distributed plant; each with its source.

Units SI throughout (m, s, kg, W, K); temperatures in °C where named so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

KELVIN = 273.15
TAYLOR_CRITICAL = 1700.0          # Becker & Kaye (1962): below it the air-gap flow is laminar Couette flow, Nu = 2
LAMINAR_RE, TURBULENT_RE = 2300.0, 3000.0     # pipe flow: laminar below, Gnielinski above, linear in between
LAMINAR_NU = 3.66                 # fully developed laminar pipe flow at constant wall temperature
FLAT_PLATE_TRANSITION_RE = 5e5    # Incropera & DeWitt, flat plate: laminar boundary layer below


@dataclass(frozen=True)
class Fluid:
    rho: float     # kg/m³
    cp: float      # J/(kg K)
    k: float       # W/(m K)
    mu: float      # Pa s

    @property
    def nu(self) -> float:
        return self.mu / self.rho

    @property
    def pr(self) -> float:
        return self.mu * self.cp / self.k


def water(t_C: float) -> Fluid:
    """Liquid water at t_C (0-100 °C). Viscosity: Vogel-type fit μ = 2.414e-5·10^(247.8/(T - 140)) Pa s, T in K
    (within 2.5 % of IAPWS from 0 to 100 °C); conductivity and density: quadratic fits of tabulated values
    (Incropera & DeWitt, Table A.6)."""
    t = min(max(t_C, 0.0), 100.0)
    mu = 2.414e-5 * 10.0 ** (247.8 / (t + KELVIN - 140.0))
    k = 0.5606 + 0.00211 * t - 8.2e-6 * t * t
    rho = 1000.0 - 0.0178 * abs(t - 4.0) ** 1.7
    return Fluid(rho, 4180.0, k, mu)


def air(t_C: float) -> Fluid:
    """Dry air at 1 atm: ideal gas density, Sutherland's law for μ, k ∝ T^0.81 (fit of Incropera Table A.4)."""
    t = t_C + KELVIN
    mu = 1.716e-5 * (t / KELVIN) ** 1.5 * (KELVIN + 110.4) / (t + 110.4)
    return Fluid(101325.0 / (287.05 * t), 1007.0, 0.0241 * (t / KELVIN) ** 0.81, mu)


def gnielinski_nu(re: float, pr: float) -> float:
    """Nusselt number of pipe/duct flow: Gnielinski (1976), Nu = (f/8)(Re - 1000)Pr / (1 + 12.7·√(f/8)(Pr^⅔ - 1))
    with Petukhov's f = (0.79 ln Re - 1.64)^-2, valid 3000 < Re < 5·10⁶; laminar Nu = 3.66 below Re = 2300 and
    linear between (the transition range). Dittus–Boelter (0.023 Re^0.8 Pr^0.4) agrees within ~10 % for Re > 10⁴."""
    if re <= LAMINAR_RE:
        return LAMINAR_NU
    if re < TURBULENT_RE:
        share = (re - LAMINAR_RE) / (TURBULENT_RE - LAMINAR_RE)
        return LAMINAR_NU + share * (gnielinski_nu(TURBULENT_RE, pr) - LAMINAR_NU)
    f = (0.79 * math.log(re) - 1.64) ** -2
    return (f / 8.0) * (re - 1000.0) * pr / (1.0 + 12.7 * math.sqrt(f / 8.0) * (pr ** (2.0 / 3.0) - 1.0))


def flat_plate_nu(re: float, pr: float) -> float:
    """Mean Nusselt number over a flat plate of length L (Re = v·L/ν), Incropera & DeWitt eqs. 7.30/7.38:
    0.664 Re^½ Pr^⅓ laminar, 0.037 (Re^0.8 - 871) Pr^⅓ once the boundary layer turns turbulent (Re > 5·10⁵)."""
    if re <= FLAT_PLATE_TRANSITION_RE:
        return 0.664 * math.sqrt(re) * pr ** (1.0 / 3.0)
    return 0.037 * (re ** 0.8 - 871.0) * pr ** (1.0 / 3.0)


def fin_efficiency(h: float, k: float, thickness: float, height: float) -> float:
    """Straight rectangular fin with an adiabatic tip: η = tanh(mH)/(mH), m = √(2h/(k t)) (Incropera eq. 3.89)."""
    m_h = math.sqrt(2.0 * h / (k * thickness)) * height
    return 1.0 if m_h < 1e-9 else math.tanh(m_h) / m_h


def taylor_number(omega: float, r_mean: float, gap: float, fluid: Fluid) -> float:
    """The modified Taylor number Ta_m = Ta/F_g of the air gap, Ta = ρ²ω² r_m g³/μ² (Becker & Kaye 1962, as used by
    Boglietti et al., IEEE TIE 2009, eqs. 5-7, and reviewed by Howey, Childs & Holmes, IEEE TIE 2012):
    F_g = π⁴/(1697·P)·(2r_m - 2.304 g)/(2r_m - g), P = 0.0571(1 - 0.652 x) + 0.00056/(1 - 0.652 x),
    x = (g/r_m)/(1 - g/r_m); F_g ≈ 1 for thin gaps."""
    ta = (fluid.rho * omega) ** 2 * r_mean * gap ** 3 / fluid.mu ** 2
    x = (gap / r_mean) / (1.0 - gap / r_mean)
    p = 0.0571 * (1.0 - 0.652 * x) + 0.00056 / (1.0 - 0.652 * x)
    f_g = math.pi ** 4 / (1697.0 * p) * (2.0 * r_mean - 2.304 * gap) / (2.0 * r_mean - gap)
    return ta / f_g


def airgap_nu(ta_m: float) -> float:
    """Air-gap Nusselt number (hydraulic diameter 2g) in the modified Taylor number, Becker & Kaye (1962) as in
    Boglietti et al. (2009): Nu = 2 (laminar, conduction only) below Ta_m = 1700; 0.128·Ta_m^0.367 up to 10⁴
    (Taylor vortices); 0.409·Ta_m^0.241 up to 10⁷ (turbulent)."""
    if ta_m < TAYLOR_CRITICAL:
        return 2.0
    if ta_m < 1e4:
        return 0.128 * ta_m ** 0.367
    return 0.409 * ta_m ** 0.241


def airgap_h(omega: float, r_mean: float, gap: float, fluid: Fluid) -> float:
    """Air-gap heat transfer coefficient h = Nu·k/(2g), from stator bore to rotor surface."""
    return airgap_nu(taylor_number(omega, r_mean, gap, fluid)) * fluid.k / (2.0 * gap)


def end_space_h(v: float, k1: float, k2: float, k3: float) -> float:
    """End-space (end winding, end cap, rotor end) convection h = k1·(1 + k2·v^k3), v the rotor's peripheral speed in
    m/s (Boglietti et al. 2009, Table III; Staton et al. use k1 ≈ 15, k2 ≈ 0.4, k3 ≈ 0.9)."""
    return k1 * (1.0 + k2 * abs(v) ** k3)


def rotating_cylinder_h(omega: float, radius: float, fluid: Fluid) -> float:
    """Forced convection from a cylinder rotating in still air (an out-runner's outside): Nu_D = 0.133·Re_D^⅔·Pr^⅓,
    Re_D = ω D²/ν (Becker 1963, as reviewed by Howey, Childs & Holmes 2012; valid Re_D < 4.3·10⁵)."""
    d = 2.0 * radius
    re = abs(omega) * d * d / fluid.nu
    return 0.133 * re ** (2.0 / 3.0) * fluid.pr ** (1.0 / 3.0) * fluid.k / d


def windage_W(omega: float, radius: float, length: float, gap: float, fluid: Fluid) -> float:
    """Air friction of the rotor in its gap: P = C_f·π·ρ·ω³·r⁴·L with the Couette-flow friction coefficient of
    Bilgen & Boulos (1973) as used by Saari (1998): C_f = 1.03 (g/r)^0.3 Re^-0.5 for Re < 10⁴, 0.065 (g/r)^0.3
    Re^-0.2 above, Re = ρ ω r g / μ."""
    omega = abs(omega)
    if omega == 0.0:
        return 0.0
    re = fluid.rho * omega * radius * gap / fluid.mu
    c_f = (1.03 * re ** -0.5 if re < 1e4 else 0.065 * re ** -0.2) * (gap / radius) ** 0.3
    return c_f * math.pi * fluid.rho * omega ** 3 * radius ** 4 * length


def slot_conductivity(fill: float, k_copper: float, k_resin: float) -> float:
    """Transverse conductivity of an impregnated winding: round conductors (fill factor) in resin, the
    Hashin–Shtrikman/Ollendorff formula k = k_r·((1 + φ)k_c + (1 - φ)k_r)/((1 - φ)k_c + (1 + φ)k_r) (Meeker 2021,
    'Equivalent thermal conductivity of encapsulated magnet wire'; the equivalent-conductivity slot model of Staton
    et al. 2005 and Boglietti et al. 2009 with k_eq ≈ 0.4-1.5 W/mK for typical fills)."""
    return k_resin * ((1.0 + fill) * k_copper + (1.0 - fill) * k_resin) / ((1.0 - fill) * k_copper
                                                                         + (1.0 + fill) * k_resin)
