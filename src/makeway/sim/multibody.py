"""CommonRoad's multi-body vehicle model, written out for speed (issue 30).

:func:`multibody_rhs` returns the right-hand side ``f(x, u)`` of the 29-state multi-body model of
Althoff & Würsching, *CommonRoad: Vehicle Models* (TUM, 2020, the multi-body model; PyPI
``commonroad-vehicle-models`` 3.0.2, ``vehiclemodels.vehicle_dynamics_mb``), for one parameter set:
the same equations and the same parameters, so it agrees with the package's function to rounding
(``tests/test_multibody.py``: ≤ 1e-9 relative on random states of all three published cars, dry and
wet). It takes about half the time (11 against 22 µs per evaluation on the project's shared
cores) because the parameters are turned into constants once (the package looks up every
parameter on every call, evaluates each tyre through four function calls and builds its lists
element by element), a Runge–Kutta stage is evaluated without building its state list, and a few
terms are simplified exactly:

* in the Magic Formula the stiffness factor is ``B = K/(C·D)`` with ``K = p_k·F_z`` and
  ``D = μ·F_z``, so ``B = p_k/(C·μ)``: the wheel load cancels;
* ``cos(atan z) = 1/√(1 + z²)``;
* the sprung mass's pitch moment reuses the longitudinal force sum ``ΣX``.

States (SI units; positions world frame at the centre of gravity, velocities body frame):
``x, y, δ, v_x, ψ, ψ̇`` (0–5), sprung mass roll ``φ, φ̇``, pitch ``θ, θ̇``, ``v_y``, height ``z, ż``
(6–12), front unsprung mass roll ``φ_f, φ̇_f``, ``v_yf``, ``z_f, ż_f`` (13–17), the same at the rear
(18–22), wheel speeds LF, RF, LR, RR in rad/s (23–26), the compliant joints' lateral deflections
``Δy_f, Δy_r`` (27, 28). Inputs: steering-angle velocity (rad/s) and longitudinal acceleration
(m/s²), both clipped to the parameter set's limits as the package does. Below ``|v_x| < 0.1`` m/s
the model switches to its kinematic form; that branch calls the package's own function.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb

__all__ = ["KINEMATIC_BELOW_MPS", "Derivative", "multibody_rhs"]

G = 9.81
"""Gravity (m/s²), the package's value."""

Derivative = Callable[..., list[float]]
"""A model's right-hand side for one parameter set: ``f(x, u)`` is ``ẋ`` at state ``x`` with inputs
``u``; ``f(x, u, k, c)`` is ``ẋ`` at the state ``x + c·k`` (a Runge–Kutta stage)."""

KINEMATIC_BELOW_MPS = 0.1
"""Below this ``|v_x|`` the model's equations switch to the kinematic single track."""


def multibody_rhs(p: Any) -> Derivative:
    """The multi-body model's derivative ``f(x, u) -> ẋ`` (29 states, 2 inputs; module docstring)
    for the CommonRoad parameter set ``p`` (``vehiclemodels.parameters_vehicle*``, possibly with
    scaled tyre friction); ``f(x, u, k, c)`` is ẋ at ``x + c·k``. ``x`` is not modified."""
    sp, lp, t = p.steering, p.longitudinal, p.tire
    # steering and acceleration limits
    d_min, d_max, dd_min, dd_max = sp.min, sp.max, sp.v_min, sp.v_max
    v_min, v_max, v_switch, a_max = lp.v_min, lp.v_max, lp.v_switch, lp.a_max
    # geometry and masses
    a, b, R = p.a, p.b, p.R_w
    hf, hr = 0.5 * p.T_f, 0.5 * p.T_r  # half track widths
    hs = p.h_s
    arm_f, arm_r = p.h_raf - R, p.h_rar - R  # roll-axis heights above the wheel centres
    m, ms, muf, mur = p.m, p.m_s, p.m_uf, p.m_ur
    inv_iys, inv_iuf, inv_iur, inv_iw = 1.0 / p.I_y_s, 1.0 / p.I_uf, 1.0 / p.I_ur, 1.0 / p.I_y_w
    ixz, iz, iphi = p.I_xz_s, p.I_z, p.I_Phi_s
    yaw_den = iz - ixz**2 / iphi
    roll_den = iphi - ixz**2 / iz
    ixz_phi, ixz_z = ixz / iphi, ixz / iz
    # springs and dampers
    kzt, klt = p.K_zt, p.K_lt
    ksf, ksdf, ksr, ksdr = p.K_sf, p.K_sdf, p.K_sr, p.K_sdr
    ktsf, ktsr = p.K_tsf / p.T_f, p.K_tsr / p.T_r  # anti-roll bars as forces per rad at each wheel
    kras, krad = p.K_ras, p.K_rad
    Df, Ef, Dr, Er = p.D_f, p.E_f, p.D_r, p.E_r
    static_f = ms * G * b / (2.0 * (a + b))  # each front spring's share of the sprung weight
    static_r = ms * G * a / (2.0 * (a + b))
    # torque split: drive and brake torque per m/s² of demanded acceleration, front and rear wheel
    mR = m * R
    brake_f, brake_r = 0.5 * p.T_sb * mR, 0.5 * (1.0 - p.T_sb) * mR
    drive_f, drive_r = 0.5 * p.T_se * mR, 0.5 * (1.0 - p.T_se) * mR

    # Magic Formula coefficients (Pacejka 2012, scaling factors 1, no turn slip, as the package)
    cx, dx1, dx3, ex, kx, hx, vx1 = t.p_cx1, t.p_dx1, t.p_dx3, t.p_ex1, t.p_kx1, t.p_hx1, t.p_vx1
    cy, dy1, dy3, ey, ky = t.p_cy1, t.p_dy1, t.p_dy3, t.p_ey1, t.p_ky1
    hy1, hy3, vy1, vy3 = t.p_hy1, t.p_hy3, t.p_vy1, t.p_vy3
    rbx1, rbx2, rcx, rex, rhx = t.r_bx1, t.r_bx2, t.r_cx1, t.r_ex1, t.r_hx1
    rby1, rby2, rby3, rcy, rey, rhy = t.r_by1, t.r_by2, t.r_by3, t.r_cy1, t.r_ey1, t.r_hy1
    rvy1, rvy3, rvy4, rvy5, rvy6 = t.r_vy1, t.r_vy3, t.r_vy4, t.r_vy5, t.r_vy6
    # without a camber term (p_dx3 = 0, as in all three published sets) μ_x and B_x are constants
    camber_free_x = dx3 == 0.0
    mu_x0 = dx1 * (1.0 - dx3 * 0.0)
    bx0 = kx / (cx * mu_x0)
    atan, cos, sin, sqrt = math.atan, math.cos, math.sin, math.sqrt

    def tyre(slip: float, alpha: float, gamma: float, fz: float) -> tuple[float, float]:
        """Longitudinal and lateral tyre force (N) for combined slip: longitudinal slip ``slip``,
        slip angle ``alpha`` (rad), camber ``gamma`` (rad), wheel load ``fz`` (N)."""
        g2 = gamma * gamma
        # pure longitudinal slip (the package's sign convention: κ = −slip)
        if camber_free_x:
            mu_x, bx = mu_x0, bx0
        else:
            mu_x = dx1 * (1.0 - dx3 * g2)
            bx = kx / (cx * mu_x)
        zx = bx * (hx - slip)
        fx0 = mu_x * fz * sin(cx * atan(zx - ex * (zx - atan(zx))) + fz * vx1)
        # pure lateral slip; horizontal and vertical shifts grow with |γ| and take its sign
        mu_y = dy1 * (1.0 - dy3 * g2)
        if gamma > 0.0:
            ay = alpha + hy1 + hy3 * gamma
            svy = fz * (vy1 + vy3 * gamma)
        elif gamma < 0.0:
            ay = alpha - hy1 + hy3 * gamma
            svy = fz * (vy3 * gamma - vy1)
        else:
            ay = alpha
            svy = 0.0
        zy = ky / (cy * mu_y) * ay
        peak_y = mu_y * fz
        fy0 = peak_y * sin(cy * atan(zy - ey * (zy - atan(zy)))) + svy
        # combined slip: weighting functions G_xα and G_yκ
        z = rbx2 * slip
        z = rbx1 / sqrt(1.0 + z * z)  # B_xα
        z0, z1 = z * rhx, z * (alpha + rhx)
        fx = fx0 / cos(rcx * atan(z0 - rex * (z0 - atan(z0)))) * cos(rcx * atan(z1 - rex * (z1 - atan(z1))))
        z = rby2 * (alpha - rby3)
        z = rby1 / sqrt(1.0 + z * z)  # B_yκ
        z0, z1 = z * rhy, z * (slip + rhy)
        z = rvy4 * alpha
        d_vk = peak_y * (rvy1 + rvy3 * gamma) / sqrt(1.0 + z * z)
        svk = d_vk * sin(rvy5 * atan(rvy6 * slip))
        fy = (
            fy0 / cos(rcy * atan(z0 - rey * (z0 - atan(z0)))) * cos(rcy * atan(z1 - rey * (z1 - atan(z1))))
            + svk
        )
        return fx, fy

    def rhs(
        x: Sequence[float], u: Sequence[float], k: Sequence[float] | None = None, c: float = 0.0
    ) -> list[float]:
        """ẋ of the multi-body model at state ``x`` (29) with inputs ``u`` (steering rate, a_x);
        with ``k``, at the state ``x + c·k`` (a Runge–Kutta stage, without building it)."""
        (
            _,
            _,
            delta,
            vx,
            psi,
            r,
            phi,
            dphi,
            theta,
            dtheta,
            vy,
            z,
            dz,
            phi_f,
            dphi_f,
            vy_f,
            z_f,
            dz_f,
            phi_r,
            dphi_r,
            vy_r,
            z_r,
            dz_r,
            w_lf,
            w_rf,
            w_lr,
            w_rr,
            dy_f,
            dy_r,
        ) = x
        if k is not None:  # the stage's state (positions do not enter the derivative)
            delta, vx, psi, r = delta + c * k[2], vx + c * k[3], psi + c * k[4], r + c * k[5]
            phi, dphi, theta, dtheta = phi + c * k[6], dphi + c * k[7], theta + c * k[8], dtheta + c * k[9]
            vy, z, dz = vy + c * k[10], z + c * k[11], dz + c * k[12]
            phi_f, dphi_f, vy_f = phi_f + c * k[13], dphi_f + c * k[14], vy_f + c * k[15]
            z_f, dz_f = z_f + c * k[16], dz_f + c * k[17]
            phi_r, dphi_r, vy_r = phi_r + c * k[18], dphi_r + c * k[19], vy_r + c * k[20]
            z_r, dz_r = z_r + c * k[21], dz_r + c * k[22]
            w_lf, w_rf, w_lr, w_rr = w_lf + c * k[23], w_rf + c * k[24], w_lr + c * k[25], w_rr + c * k[26]
            dy_f, dy_r = dy_f + c * k[27], dy_r + c * k[28]
        if abs(vx) < KINEMATIC_BELOW_MPS:
            y = list(x) if k is None else [xi + c * ki for xi, ki in zip(x, k, strict=True)]
            return list(vehicle_dynamics_mb(y, list(u), p))
        # input limits (the package's steering_constraints and acceleration_constraints)
        d_rate, acc = u[0], u[1]
        if (delta <= d_min and d_rate <= 0.0) or (delta >= d_max and d_rate >= 0.0):
            d_rate = 0.0
        elif d_rate <= dd_min:
            d_rate = dd_min
        elif d_rate >= dd_max:
            d_rate = dd_max
        pos_limit = a_max * v_switch / vx if vx > v_switch else a_max
        if (vx <= v_min and acc <= 0.0) or (vx >= v_max and acc >= 0.0):
            acc = 0.0
        elif acc <= -a_max:
            acc = -a_max
        elif acc >= pos_limit:
            acc = pos_limit

        cd, sd = cos(delta), sin(delta)
        cphi, sphi = cos(phi), sin(phi)
        cpf, spf = cos(phi_f), sin(phi_f)
        cpr, spr = cos(phi_r), sin(phi_r)
        # wheel loads from the tyres' vertical compliance
        base_f, base_r = z_f + R * (cpf - 1.0), z_r + R * (cpr - 1.0)
        fz_lf, fz_rf = (base_f - hf * spf) * kzt, (base_f + hf * spf) * kzt
        fz_lr, fz_rr = (base_r - hr * spr) * kzt, (base_r + hr * spr) * kzt
        # wheel-centre speeds along each wheel (never negative)
        v_front, v_rear = vy + a * r, vy - b * r  # lateral speed at the axles
        vl_f, vr_f, vl_r, vr_r = vx + hf * r, vx - hf * r, vx + hr * r, vx - hr * r  # at each wheel
        across = v_front * sd
        u_lf, u_rf, u_lr, u_rr = vl_f * cd + across, vr_f * cd + across, vl_r, vr_r
        if u_lf < 0.0:
            u_lf = 0.0
        if u_rf < 0.0:
            u_rf = 0.0
        if u_lr < 0.0:
            u_lr = 0.0
        if u_rr < 0.0:
            u_rr = 0.0
        s_lf, s_rf = 1.0 - R * w_lf / u_lf, 1.0 - R * w_rf / u_rf
        s_lr, s_rr = 1.0 - R * w_lr / u_lr, 1.0 - R * w_rr / u_rr
        # slip angles
        lat_f = v_front - dphi_f * (R - z_f)
        lat_r = v_rear - dphi_r * (R - z_r)
        al_lf = atan(lat_f / vl_f) - delta
        al_rf = atan(lat_f / vr_f) - delta
        al_lr = atan(lat_r / vl_r)
        al_rr = atan(lat_r / vr_r)
        # suspension travel and its rate at each corner
        gap_f, gap_r = hs - R + z_f - z, hs - R + z_r - z
        roll_f, roll_r = phi - phi_f, phi - phi_r
        droll_f, droll_r = dphi - dphi_f, dphi - dphi_r
        lift_f = gap_f / cphi - hs + R + a * theta
        lift_r = gap_r / cphi - hs + R - b * theta
        zs_lf, zs_rf = lift_f + hf * roll_f, lift_f - hf * roll_f
        zs_lr, zs_rr = lift_r + hr * roll_r, lift_r - hr * roll_r
        heave_f, heave_r = dz_f - dz, dz_r - dz
        rate_f = heave_f + a * dtheta
        rate_r = heave_r - b * dtheta
        dzs_lf, dzs_rf = rate_f + hf * droll_f, rate_f - hf * droll_f
        dzs_lr, dzs_rr = rate_r + hr * droll_r, rate_r - hr * droll_r
        # camber from roll and suspension travel
        g_lf = phi + Df * zs_lf + Ef * zs_lf * zs_lf
        g_rf = phi - Df * zs_rf - Ef * zs_rf * zs_rf
        g_lr = phi + Dr * zs_lr + Er * zs_lr * zs_lr
        g_rr = phi - Dr * zs_rr - Er * zs_rr * zs_rr
        fx_lf, fy_lf = tyre(s_lf, al_lf, g_lf, fz_lf)
        fx_rf, fy_rf = tyre(s_rf, al_rf, g_rf, fz_rf)
        fx_lr, fy_lr = tyre(s_lr, al_lr, g_lr, fz_lr)
        fx_rr, fy_rr = tyre(s_rr, al_rr, g_rr, fz_rr)

        # compliant joints between sprung and unsprung masses (lateral)
        ddy_f = v_front - vy_f
        ddy_r = v_rear - vy_r
        defl_f = gap_f * sphi - dy_f * cphi - arm_f * sin(roll_f)
        defl_r = gap_r * sphi - dy_r * cphi - arm_r * sin(roll_r)
        ddefl_f = (
            (gap_f * cphi + dy_f * sphi) * dphi
            + heave_f * sphi
            - ddy_f * cphi
            - arm_f * cos(roll_f) * droll_f
        )
        ddefl_r = (
            (gap_r * cphi + dy_r * sphi) * dphi
            + heave_r * sphi
            - ddy_r * cphi
            - arm_r * cos(roll_r) * droll_r
        )
        f_raf = defl_f * kras + ddefl_f * krad
        f_rar = defl_r * kras + ddefl_r * krad
        # suspension forces (bump stops, squat and lift neglected, as in the model)
        f_slf = static_f - zs_lf * ksf - dzs_lf * ksdf + roll_f * ktsf
        f_srf = static_f - zs_rf * ksf - dzs_rf * ksdf - roll_f * ktsf
        f_slr = static_r - zs_lr * ksr - dzs_lr * ksdr + roll_r * ktsr
        f_srr = static_r - zs_rr * ksr - dzs_rr * ksdr - roll_r * ktsr

        fx_f, fy_f, fx_r, fy_r = fx_lf + fx_rf, fy_lf + fy_rf, fx_lr + fx_rr, fy_lr + fy_rr
        susp_f, susp_r = f_slf + f_srf, f_slr + f_srr
        susp, joints = susp_f + susp_r, f_raf + f_rar
        lat_front = fy_f * cd + fx_f * sd  # front tyres' force across the body
        # sprung mass: forces and moments
        sum_x = fx_r + fx_f * cd - fy_f * sd
        sum_n = (
            fy_f * a * cd
            + fx_f * a * sd
            + (fy_rf - fy_lf) * hf * sd
            + (fx_lf - fx_rf) * hf * cd
            + (fx_lr - fx_rr) * hr
            - fy_r * b
        )
        sum_ys = joints * cphi + susp * sphi
        sum_l = (
            hf * (f_slf - f_srf)
            + hr * (f_slr - f_srr)
            - f_raf / cphi * (gap_f - arm_f * cpf)
            - f_rar / cphi * (gap_r - arm_r * cpr)
        )
        sum_zs = susp * cphi - joints * sphi
        sum_ms = a * susp_f - b * susp_r + sum_x * (hs - z)
        # unsprung masses
        sum_luf = (
            hf * (f_srf - f_slf)
            - f_raf * arm_f
            + fz_lf * (R * spf + hf * cpf - klt * fy_lf)
            - fz_rf * (-R * spf + hf * cpf + klt * fy_rf)
            - lat_front * (R - z_f)
        )
        sum_lur = (
            hr * (f_srr - f_slr)
            - f_rar * arm_r
            + fz_lr * (R * spr + hr * cpr - klt * fy_lr)
            - fz_rr * (-R * spr + hr * cpr + klt * fy_rr)
            - fy_r * (R - z_r)
        )
        sum_zuf = fz_lf + fz_rf + f_raf * sphi - susp_f * cphi
        sum_zur = fz_lr + fz_rr + f_rar * sphi - susp_r * cphi
        sum_yuf = lat_front - f_raf * cphi - susp_f * sphi
        sum_yur = fy_r - f_rar * cphi - susp_r * sphi
        # drive or brake torque on each wheel
        if acc > 0.0:
            t_f, t_r = drive_f * acc, drive_r * acc
        else:
            t_f, t_r = brake_f * acc, brake_r * acc
        beta = atan(vy / vx)
        speed = sqrt(vx * vx + vy * vy)
        r_vx = r * vx
        return [
            cos(beta + psi) * speed,
            sin(beta + psi) * speed,
            d_rate,
            sum_x / m + r * vy,
            r,
            (sum_n + ixz_phi * sum_l) / yaw_den,
            dphi,
            (ixz_z * sum_n + sum_l) / roll_den,
            dtheta,
            sum_ms * inv_iys,
            sum_ys / ms - r_vx,
            dz,
            G - sum_zs / ms,
            dphi_f,
            sum_luf * inv_iuf,
            sum_yuf / muf - r_vx,
            dz_f,
            G - sum_zuf / muf,
            dphi_r,
            sum_lur * inv_iur,
            sum_yur / mur - r_vx,
            dz_r,
            G - sum_zur / mur,
            (t_f - R * fx_lf) * inv_iw if w_lf >= 0.0 else 0.0,
            (t_f - R * fx_rf) * inv_iw if w_rf >= 0.0 else 0.0,
            (t_r - R * fx_lr) * inv_iw if w_lr >= 0.0 else 0.0,
            (t_r - R * fx_rr) * inv_iw if w_rr >= 0.0 else 0.0,
            ddy_f,
            ddy_r,
        ]

    return rhs
