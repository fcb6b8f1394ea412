"""Wave-optics reference for the iridescent layer (issue #17 item 3).

An independent check of Velinov, Werner & Hullin 2018 §3.1 (eqs. 1-11) and of the energy-consistent
base weight (``precompute.iridescence.energy``): scalar Kirchhoff scattering of an *explicit*
scratched height field h(x) (rectangular, V and rounded grooves; one scratch, a few crossing ones),
inside the Gaussian coherence window g(x) = exp(−|x|²/2σ²) of §3.1, computed per wavelength by FFT of
the windowed reflected field

    u_q(x) = g(x) · exp(i q h(x)),     q = k (ω_i,z + ω_o,z)   (angle-dependent phase, Werner et al. 2017)
                                       q = 2k                   (eq. 4's normal-incidence phase)

whose far field U(ξ) = ∫ u_q(x) e^{ik ξ·x} dx (ξ = ω_i,t + ω_o,t, direction cosines) gives the reflected
radiance per unit ξ, |U|²/(A_C λ²) (eq. 1's normalisation; ∫ dξ of it is 1 by Parseval for any h).
Because q depends on the outgoing direction, u_q is transformed at Chebyshev nodes q_j spanning the
propagating range and |U| at each ξ is the barycentric interpolant at q(ξ) (exact for the rectangular
groove's two levels; checked against a direct DFT in tests/iridescence/test_iridescence_wave.py).

Compared with the layer's model (the numpy twin of the shader): the scratch lobe W²|𝒟|² sinc²(πWξ₂/λ)
|η_s|² e^{−σ²k²ξ₁²}/(A_C λ²) (eqs. 3, 9-11, 7: incoherent over scratches) and the base weight
(energy-consistent 1 − N(E), or eq. 6's 1 − ρ), the base's lobe being the window's own Gaussian.
"Specular" = the cone |ξ| < 6/(σk) around the mirror direction (where ℬ lives); "diffracted" = the
propagating rest.  The model only knows a rectangular groove of the same W and D.

Run: ``.venv/bin/python -m bench iridescence_wave [--quick]`` → bench/out/iridescence_wave.md,
bench/out/iridescence_wave_lobes.png.
"""
from __future__ import annotations

import math

import numpy as np

from scratch_materials.precompute.iridescence import energy as en
from scratch_materials.precompute.iridescence import model as ir

SIGMA_UM = 60.0
PROFILES = ("rect", "v", "round")
PHASES = ("angle", "normal")
RGB_UM = tuple(float(x) for x in ir.RGB_WAVELENGTHS_UM)
CONE = 6.0          # specular cone half-width in units of 1/(σk)


# ----------------------------------------------------------------------------- height fields
def groove_height(d, W, D, profile):
    """Height (µm, ≤ 0) of a groove of width W and depth D at signed distance d (µm) across it.

    rect: −D on |d| < W/2; v: −D(1 − 2|d|/W); round: −D√(1 − (2d/W)²) (elliptic arc, a rounded tool)."""
    a = 2.0 * np.abs(np.asarray(d, float)) / W
    inside = a < 1.0
    if profile == "rect":
        h = np.where(inside, -D, 0.0)
    elif profile == "v":
        h = np.where(inside, -D * (1.0 - a), 0.0)
    elif profile == "round":
        h = np.where(inside, -D * np.sqrt(np.maximum(0.0, 1.0 - a * a)), 0.0)
    else:
        raise ValueError(f"profile must be one of {', '.join(PROFILES)}; got {profile!r}")
    return h


def heights_2d(X, Y, scratches):
    """Height field of several straight grooves (deepest wins where they cross).

    ``scratches``: iterable of (angle_rad, offset_um, W_um, D_um, profile); groove m runs along
    (cos a, sin a) at signed distance ``offset`` from the origin."""
    h = np.zeros_like(X)
    for a, off, W, D, prof in scratches:
        d = -np.sin(a) * X + np.cos(a) * Y - off
        h = np.minimum(h, groove_height(d, W, D, prof))
    return h


# ----------------------------------------------------------------------------- far field by FFT
def _cheb_nodes(lo, hi, K):
    j = np.arange(K)
    x = np.cos((2 * j + 1) * np.pi / (2 * K))
    return 0.5 * (lo + hi) + 0.5 * (hi - lo) * x, x


def _bary_weights(K):
    j = np.arange(K)
    return (-1.0) ** j * np.sin((2 * j + 1) * np.pi / (2 * K))


def _interp(nodes_x, vals, x):
    """Barycentric interpolation (Chebyshev points of the first kind) of vals (K, ...) at x (...)."""
    w = _bary_weights(len(nodes_x))
    diff = x[None] - nodes_x.reshape((-1,) + (1,) * x.ndim)
    exact = np.abs(diff) < 1e-14
    diff = np.where(exact, 1.0, diff)
    c = w.reshape((-1,) + (1,) * x.ndim) / diff
    out = (c * vals).sum(0) / c.sum(0)
    hit = exact.any(0)
    if hit.any():
        out = np.where(hit, (vals * exact).sum(0), out)
    return out


def _nodes_needed(q_lo, q_hi, hmax):
    """Chebyshev nodes for exp(i q h), q ∈ [q_lo, q_hi], |h| ≤ hmax: error ~ (Δq hmax/4)^K / K! ≪ 1e-8."""
    r = 0.5 * (q_hi - q_lo) * hmax
    return int(min(64, max(2, math.ceil(2 * r + 12))))


def far_field_1d(h, dy, lam_um, sigma_um, q_of_xi, q_range):
    """U(ξ₂) = Σ g(y) e^{i q(ξ₂) h(y)} e^{ikξ₂y} dy on the FFT's own bins, for a field that depends on y only.

    ``h`` (n,) heights on the centred grid y = (j − n/2) dy; ``q_of_xi(xi) -> q`` the phase factor per
    output; q_range (lo, hi) the Chebyshev interval (lo = hi: one FFT).  Returns (xi2 ascending, U complex)."""
    n = h.size
    y = (np.arange(n) - n // 2) * dy
    g = np.exp(-y * y / (2 * sigma_um ** 2))
    f = np.fft.fftfreq(n, dy)                                   # cycles per µm; numpy's e^{-2πi f j dy}
    shift = np.exp(-2j * np.pi * f * y[0])                     # → Σ u(y) e^{-2πi f y}
    lo, hi = q_range
    if hi - lo < 1e-12:
        qn, xn = np.array([lo]), None
    else:
        qn, xn = _cheb_nodes(lo, hi, _nodes_needed(lo, hi, np.abs(h).max()))
    spec = np.asarray([np.fft.fft(g * np.exp(1j * q * h)) * dy * shift for q in qn])
    xi = -f * lam_um                                            # e^{+ikξy} = e^{-2πi f y}, f = −ξ/λ
    order = np.argsort(xi)
    xi, spec = xi[order], spec[:, order]
    if xn is None:
        return xi, spec[0]
    q = np.asarray(q_of_xi(xi), float)
    t = np.clip((2 * q - (lo + hi)) / (hi - lo), -1.0, 1.0)
    return xi, _interp(xn, spec, t)


def direct_dft_1d(h, dy, lam_um, sigma_um, xi2, q_of_xi):
    """The same far field by a direct sum per ξ₂ (the test oracle for ``far_field_1d``)."""
    n = h.size
    y = (np.arange(n) - n // 2) * dy
    g = np.exp(-y * y / (2 * sigma_um ** 2))
    k = 2 * np.pi / lam_um
    xi2, q = np.asarray(xi2, float), np.asarray(q_of_xi, float)
    return np.array([np.sum(g * np.exp(1j * (qq * h + k * x * y))) * dy for x, qq in zip(xi2, q)])


# ----------------------------------------------------------------------------- one straight scratch
def incidence(theta_deg, phi_deg=90.0):
    """Local unit direction toward the light; φ from the scratch direction t = +x (90° = across)."""
    th, ph = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])


def single_scratch(profile, W, D, lam_um, wi, *, phase="angle", s_b=0.0, sigma_um=SIGMA_UM, dy=None):
    """Wave and model for one infinite groove along x at distance s_b, on the line ξ₁ = 0 (ω_o,x = −ω_i,x).

    Returns dict: xi2 (n,), prop (n,) bool (ω_o above the horizon), wave (n,) radiance per unit ξ₂
    integrated over ξ₁, model_scratch (n,) the model's scratch lobe likewise, and the energies:
    wave_spec / wave_diff (inside / outside the specular cone, propagating), model_E (energy
    weight), model_rho (eq. 17 ρ), model_scratch_spec / model_scratch_diff, cone (ξ₂ half-width)."""
    k = 2 * np.pi / lam_um
    if dy is None:
        dy = min(W / 40.0, lam_um / 4.0)
    half = 5.0 * sigma_um
    n = int(2 ** math.ceil(math.log2(2 * half / dy)))
    n = max(n, 4096)
    # resolution in ξ: λ/(n dy) must resolve the window's Gaussian lobe (width 1/(σk))
    while lam_um / (n * dy) > 0.2 / (sigma_um * k):
        n *= 2
    y = (np.arange(n) - n // 2) * dy
    h = groove_height(y - s_b, W, D, profile)
    wox = -wi[0]
    rr = math.sqrt(max(0.0, 1.0 - wox * wox))                 # chord half-length on the line ξ₁ = 0
    lo_b, hi_b = wi[1] - rr, wi[1] + rr                         # ξ₂ = ω_i,y + ω_o,y, |ω_o,y| ≤ rr
    if phase == "angle":
        def q_of(x):
            wo_y = x - wi[1]
            return k * (wi[2] + np.sqrt(np.maximum(0.0, 1.0 - wox * wox - wo_y * wo_y)))
        q_rng = (k * wi[2], k * (wi[2] + rr))
    elif phase == "normal":
        q_of, q_rng = None, (2 * k, 2 * k)
    else:
        raise ValueError(f"phase must be one of {', '.join(PHASES)}; got {phase!r}")
    xi_all, U_all = far_field_1d(h, dy, lam_um, sigma_um, q_of, q_rng)
    keep = (xi_all > lo_b) & (xi_all < hi_b)                    # propagating: ω_o above the horizon
    xi2, U = xi_all[keep], U_all[keep]
    A_C = math.pi * sigma_um ** 2
    # along the groove the field is g(x) alone: ∫|FFT_x g|² dξ₁ = λ σ √π
    wave = np.abs(U) ** 2 * sigma_um * math.sqrt(math.pi) / (lam_um * A_C)
    eta = ir.eta_s_sq(s_b, sigma_um)
    model_s = (ir.width_term(W, xi2, lam_um) * ir.depth_term(D, lam_um) * eta
               * math.sqrt(math.pi) / (sigma_um * k) / (A_C * lam_um ** 2))
    # the same lobe with the angle-dependent phase (ir.depth_term_angle; numpy option)
    wo_y = xi2 - wi[1]
    cos_sum = wi[2] + np.sqrt(np.maximum(0.0, 1.0 - wox * wox - wo_y * wo_y))
    dref = ir.depth_term(D, lam_um)
    model_a = model_s * np.where(dref > 0, ir.depth_term_angle(D, lam_um, cos_sum) / np.where(dref > 0, dref, 1.0), 0.0)
    # and at the lobe centre only (ω_o,z = ω_i,z there: D → D ω_i,z, ``evaluate(phase="view")``, the shaders')
    model_v = model_s * np.where(dref > 0, ir.depth_term(D * wi[2], lam_um) / np.where(dref > 0, dref, 1.0), 0.0)
    cone = CONE / (sigma_um * k)
    d = lam_um / (n * dy)
    spec = np.abs(xi2) < cone
    # F of the fixed direction (reciprocity: the chord of ω_o for this ω_i), scratch along +x (φ = 0)
    E = float(ir.pair_energy(np.array([eta]), np.array([W]), np.array([D]), np.array([0.0]), np.array([wi]),
                             [lam_um], sigma_um, exact=True)[0, 0])
    rho = float(ir.area_density_point(W, s_b, -np.inf, np.inf, sigma_um))
    return dict(xi2=xi2, wave=wave, model_scratch=model_s, model_angle=model_a, cone=cone,
                wave_spec=float(wave[spec].sum() * d), wave_diff=float(wave[~spec].sum() * d),
                model_E=E, model_rho=rho,
                model_scratch_spec=float(model_s[spec].sum() * d), model_scratch_diff=float(model_s[~spec].sum() * d),
                model_angle_diff=float(model_a[~spec].sum() * d), model_view_diff=float(model_v[~spec].sum() * d))


def compare_single(profile, W, D, lam_um, theta_deg, phase="angle", **kw):
    """One table row: energies (wave vs model, energy-consistent and paper weights) and lobe L1 error."""
    wi = incidence(theta_deg)
    r = single_scratch(profile, W, D, lam_um, wi, phase=phase, **kw)
    N, fac = en.normalise(r["model_E"])
    model_spec_energy = (1.0 - float(N)) + float(fac) * r["model_scratch_spec"]
    model_spec_paper = (1.0 - min(r["model_rho"], 1.0)) + r["model_scratch_spec"]
    model_diff = float(fac) * r["model_scratch_diff"]
    model_angle_diff = float(fac) * r["model_angle_diff"]
    model_view_diff = float(fac) * r["model_view_diff"]
    out = ~(np.abs(r["xi2"]) < r["cone"])
    ws = r["wave"][out].sum()
    lobe_l1 = (float(np.abs(r["wave"][out] - fac * r["model_scratch"][out]).sum() / ws)
               if r["wave_diff"] > 1e-6 else float("nan"))
    lobe_l1_angle = (float(np.abs(r["wave"][out] - fac * r["model_angle"][out]).sum() / ws)
                     if r["wave_diff"] > 1e-6 else float("nan"))
    return dict(r, lobe_l1_angle=lobe_l1_angle, model_spec_energy=model_spec_energy, model_spec_paper=model_spec_paper, model_diff=model_diff,
                lobe_l1=lobe_l1, model_angle_diff=model_angle_diff,
                model_view_diff=model_view_diff)


# ----------------------------------------------------------------------------- crossing scratches (2D)
def crossing_2d(scratches, lam_um, wi, *, phase="angle", sigma_um=SIGMA_UM, n=2048, dx=None):
    """Wave and model for a few straight grooves crossing the window (2D FFT).

    Returns dict with the wave's propagating specular / diffracted energies and the model's
    (incoherent sum of the scratch lobes, eq. 7; E of ``energy``)."""
    k = 2 * np.pi / lam_um
    if dx is None:
        dx = 8.0 * sigma_um / n
    x = (np.arange(n) - n // 2) * dx
    X, Y = np.meshgrid(x, x, indexing="xy")
    h = heights_2d(X, Y, scratches)
    g = np.exp(-(X * X + Y * Y) / (2 * sigma_um ** 2))
    f = np.fft.fftshift(np.fft.fftfreq(n, dx))
    xi = -f * lam_um                                             # ξ per FFT bin (descending)
    XI1, XI2 = np.meshgrid(xi, xi, indexing="xy")
    wox, woy = XI1 - wi[0], XI2 - wi[1]
    s2 = 1.0 - wox * wox - woy * woy
    prop = s2 > 0.0
    woz = np.sqrt(np.maximum(s2, 0.0))
    if phase == "angle":
        q, lo, hi = k * (wi[2] + woz), k * wi[2], k * (wi[2] + 1.0)
    else:
        q, lo, hi = np.full_like(woz, 2 * k), 2 * k, 2 * k
    hmax = float(np.abs(h).max())
    if hi - lo < 1e-12:
        qn, xn = np.array([lo]), None
    else:
        qn, xn = _cheb_nodes(lo, hi, _nodes_needed(lo, hi, hmax))
    ph = np.exp(-2j * np.pi * (f[:, None] * x[0] + f[None, :] * x[0]))    # the centred grid's offset
    if xn is None:
        U = np.fft.fftshift(np.fft.fft2(g * np.exp(1j * qn[0] * h))) * dx * dx * ph
    else:
        # barycentric interpolation accumulated node by node (memory: three n x n arrays)
        t = np.clip((2 * q - (lo + hi)) / (hi - lo), -1.0, 1.0)
        w = _bary_weights(len(xn))
        num = np.zeros((n, n), complex)
        den = np.zeros((n, n))
        for j, qq in enumerate(qn):
            F = np.fft.fftshift(np.fft.fft2(g * np.exp(1j * qq * h))) * dx * dx * ph
            dlt = t - xn[j]
            c = w[j] / np.where(np.abs(dlt) < 1e-12, 1e-12, dlt)
            num += c * F
            den += c
        U = num / den
        del num, den
    A_C = math.pi * sigma_um ** 2
    I = np.abs(U) ** 2 / (A_C * lam_um ** 2)
    dxi = lam_um / (n * dx)
    cone = CONE / (sigma_um * k)
    spec = (XI1 ** 2 + XI2 ** 2) < cone ** 2
    # model: eq. 7's incoherent sum of the scratch lobes on the same grid, and E (energy.py)
    M = np.zeros_like(I)
    E = 0.0
    rho = 0.0
    for a, off, W, D, _prof in scratches:
        ta, ba = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
        x1 = XI1 * ta[0] + XI2 * ta[1]
        x2 = XI1 * ba[0] + XI2 * ba[1]
        eta = float(ir.eta_s_sq(off, sigma_um))
        M += (ir.width_term(W, x2, lam_um) * ir.depth_term(D, lam_um) * eta * np.exp(-(sigma_um * k * x1) ** 2)
              / (A_C * lam_um ** 2))
        wo_c = np.array([[-wi[0], -wi[1], wi[2]]])
        E += float(ir.pair_energy(np.array([eta]), np.array([W]), np.array([D]), np.array([a]), wo_c, [lam_um],
                                  sigma_um, exact=True)[0, 0])
        rho += float(ir.area_density_point(W, off, -np.inf, np.inf, sigma_um))
    N, fac = (float(v) for v in en.normalise(E))
    d2 = dxi * dxi
    return dict(wave_spec=float(I[spec & prop].sum() * d2), wave_diff=float(I[~spec & prop].sum() * d2),
                wave_total=float(I.sum() * d2), model_E=E, model_rho=rho,
                model_spec_energy=(1.0 - N) + fac * float(M[spec & prop].sum() * d2),
                model_spec_paper=(1.0 - min(rho, 1.0)) + float(M[spec & prop].sum() * d2),
                model_diff=fac * float(M[~spec & prop].sum() * d2),
                lobe_l1=float(np.abs(I - fac * M)[~spec & prop].sum() / max(I[~spec & prop].sum(), 1e-30)))


# ----------------------------------------------------------------------------- the bench
def _fmt(v, nd=3):
    return "-" if not np.isfinite(v) else f"{v:.{nd}f}"


def single_rows(quick=False):
    cases = [("rect", 3.0, 0.1375), ("rect", 3.0, 1.0), ("rect", 8.0, 0.1375),
             ("v", 3.0, 0.1375), ("v", 3.0, 1.0), ("round", 3.0, 0.1375), ("round", 3.0, 1.0)]
    thetas = (0.0, 45.0) if quick else (0.0, 30.0, 60.0, 80.0)
    lams = (RGB_UM[1],) if quick else RGB_UM
    rows = []
    for prof, W, D in cases:
        for th in thetas:
            for lam in lams:
                a = compare_single(prof, W, D, lam, th, "angle")
                nrm = compare_single(prof, W, D, lam, th, "normal")
                rows.append([f"1 x {prof}", W, D, th, lam,
                             _fmt(a["wave_spec"]), _fmt(a["model_spec_energy"]), _fmt(a["model_spec_paper"]),
                             _fmt(a["wave_diff"]), _fmt(a["model_diff"]), _fmt(a["model_angle_diff"]),
                             _fmt(a["model_view_diff"]),
                             _fmt(nrm["wave_diff"]),
                             _fmt(a["lobe_l1"], 2), _fmt(a["lobe_l1_angle"], 2), _fmt(a["wave_spec"] + a["wave_diff"])])
    return rows


def crossing_rows(quick=False):
    n = 1024 if quick else 2048
    sets = {
        "3 x rect": [(0.0, 0.0, 3.0, 0.1375, "rect"), (math.radians(60), 10.0, 3.0, 0.1375, "rect"),
                     (math.radians(-50), -15.0, 5.0, 0.1375, "rect")],
        "3 x V": [(0.0, 0.0, 3.0, 0.1375, "v"), (math.radians(60), 10.0, 3.0, 0.1375, "v"),
                  (math.radians(-50), -15.0, 5.0, 0.1375, "v")],
        "2 x rect, 1 um": [(0.0, 5.0, 4.0, 1.0, "rect"), (math.radians(80), -5.0, 4.0, 1.0, "rect")],
    }
    thetas = (0.0,) if quick else (0.0, 45.0)
    rows = []
    for name, sc in sets.items():
        for th in thetas:
            wi = incidence(th, 30.0)
            lam = RGB_UM[1]
            a = crossing_2d(sc, lam, wi, n=n)
            rows.append([name, th, lam, _fmt(a["wave_spec"]), _fmt(a["model_spec_energy"]),
                         _fmt(a["model_spec_paper"]), _fmt(a["wave_diff"]), _fmt(a["model_diff"]),
                         _fmt(a["lobe_l1"], 2), _fmt(a["wave_total"])])
    return rows


def phase_departure_rows():
    """Where eq. 4's normal-incidence |𝒟|² = 2 − 2cos(2kD) departs from the angle-dependent
    2 − 2cos(kD(cosθ_i + cosθ_o)): the smallest cosθ_i + cosθ_o (and the equal-angle θ) where the
    ratio leaves [0.9, 1.1], per depth (rectangular groove, λ = 532 nm)."""
    lam = RGB_UM[1]
    k = 2 * np.pi / lam
    rows = []
    for D in (0.05, 0.1375, 0.266, 0.5, 1.0):
        c = np.linspace(2.0, 0.0, 20001)                       # cosθ_i + cosθ_o
        ref = 2 - 2 * math.cos(2 * k * D)
        val = 2 - 2 * np.cos(k * D * c)
        r = val / max(ref, 1e-12)
        bad = np.nonzero(np.abs(r - 1.0) > 0.1)[0]
        if bad.size:
            cb = float(c[bad[0]])
            th = math.degrees(math.acos(min(1.0, cb / 2)))
            rows.append([D, _fmt(ref, 2), _fmt(cb, 3), _fmt(th, 1)])
        else:
            rows.append([D, _fmt(ref, 2), "never", "-"])
    return rows


def lobe_figure(path):
    """Wave vs model lobes (one rectangular / V groove, normal and 60° incidence), log scale."""
    from bench._util import pyplot

    plt = pyplot()
    fig, axs = plt.subplots(2, 2, figsize=(10, 6.5), sharey=True)
    for i, prof in enumerate(("rect", "v")):
        for j, th in enumerate((0.0, 60.0)):
            ax = axs[i, j]
            for lam, col in zip(RGB_UM, ("r", "g", "b")):
                a = compare_single(prof, 3.0, 0.1375, lam, th, "angle")
                nrm = compare_single(prof, 3.0, 0.1375, lam, th, "normal")
                x = a["xi2"]
                ax.semilogy(x, a["wave"] + 1e-9, col + "-", lw=1.0, label=f"wave {lam * 1e3:.0f} nm" if i == j == 0 else None)
                ax.semilogy(x, nrm["wave"] + 1e-9, col + ":", lw=0.8)
                ax.semilogy(x, a["model_scratch"] + 1e-9, col + "--", lw=0.8,
                            label="model (eqs. 3-11)" if (i == j == 0 and col == "r") else None)
            ax.set_ylim(1e-6, 1e3)
            ax.set_title(f"{prof} groove W 3 µm, D 137.5 nm, θi = {th:.0f}°", fontsize=9)
            ax.set_xlabel("ξ₂ (across the scratch)")
    axs[0, 0].legend(fontsize=7)
    axs[0, 0].set_ylabel("radiance per unit ξ₂ (∫ dξ₁)")
    fig.suptitle("Kirchhoff FFT reference (solid: angle-dependent phase, dotted: eq. 4's) vs the layer's model",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv) -> int:
    from bench._util import format_table, out_path

    quick = "--quick" in argv
    s_rows = single_rows(quick)
    c_rows = crossing_rows(quick)
    p_rows = phase_departure_rows()
    t1 = format_table(["scratch", "W um", "D um", "theta_i", "lambda um", "wave spec", "model spec (energy)",
                       "model spec (paper 1-rho)", "wave diff", "model diff", "model diff (angle phase)",
                       "model diff (view phase)",
                       "wave diff (eq.4 phase)",
                       "lobe L1", "lobe L1 (angle phase)", "wave total"], s_rows)
    t2 = format_table(["scratches", "theta_i", "lambda um", "wave spec", "model spec (energy)",
                       "model spec (paper)", "wave diff", "model diff", "lobe L1", "wave total"], c_rows)
    t3 = format_table(["D um", "|D|^2 eq. 4", "cos th_i + cos th_o where |ratio - 1| > 10 %",
                       "equal-angle theta (deg)"], p_rows)
    notes = __doc__.split("Run:")[0].strip()
    text = ("# bench: iridescence_wave\n\n" + notes + "\n\n## One groove through the window centre (ξ₁ = 0 line, "
            "incidence across the scratch)\n\nwave spec / diff: energy of the Kirchhoff field inside / outside the "
            f"specular cone (|ξ| < {CONE:g}/(σk)), propagating only; model spec = base weight + scratch lobe in the "
            "cone (energy-consistent, or eq. 6's 1 − ρ); model diff = the scratch lobe outside (with eq. 4's phase, and with the angle-dependent "
            "phase of ``model.depth_term_angle``, and with it at the lobe centre only, 'view' = D cosθ: the "
            "shader option); wave diff (eq. 4 phase) = the Kirchhoff field computed with q = 2k; lobe L1 = "
            "∫|wave − model| / ∫wave outside the cone.\n\n" + t1 +
            "\n\n## Crossing grooves (2D FFT, σ = 60 µm, incidence azimuth 30° from the first groove)\n\n" + t2 +
            "\n\n## Where eq. 4's normal-incidence phase departs from the angle-dependent phase\n\n" + t3 + "\n")
    out_path("iridescence_wave.md").write_text(text)
    print(text)
    lobe_figure(out_path("iridescence_wave_lobes.png"))
    return 0
