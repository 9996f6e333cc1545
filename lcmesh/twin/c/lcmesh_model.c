/* lc-mesh twin: physics of a Frontier-style liquid-cooling plant.
 *
 * Blade groups are heat capacitors integrated exactly over the step (exponential
 * update, stable for any step); coolant volumes, the hot-water (HTW) loop, the tower
 * basins and the inner PID loops advance in explicit sub-steps where every volume's
 * outflow enthalpy is exactly its neighbour's inflow, so energy is conserved to
 * rounding. Equations and parameters: docs/twin.md.
 */
#include <math.h>
#include <string.h>

#include "lcmesh_model.h"

#define CP_WATER 4186.0 /* J/(kg K) */
#define RHO_WATER 997.0 /* kg/m^3 */
#define GRAVITY 9.80665
#define DERIV_FILTER_N 10.0

#define IN(name, i) (m->r[OFF_##name + (i)])
#define OUT(name, i) (m->r[OFF_##name + (i)])

static double clampd(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }

/* A plant-deviation input (the plant differs from its description: calibration, fouling): a factor,
 * 1 when non-finite, clamped to [0.1, 10]. */
static double deviation(const Model *m, int vr) {
    double f = m->r[vr];
    return isfinite(f) ? clampd(f, 0.1, 10.0) : 1.0;
}

/* PID with derivative on the measurement (implicitly filtered) and conditional
 * integration (no wind-up while the output is saturated in the error's direction).
 * err = direction * (setpoint - measurement); returns the unclamped output. */
static double pid_update(PidState *s, double k, double ti, double td, double err, double meas,
                         double direction, double dt, double u_min, double u_max) {
    double tf = td / DERIV_FILTER_N;
    if (td > 0.0) {
        s->deriv = (tf * s->deriv - direction * td * (meas - s->meas_prev)) / (tf + dt);
    }
    s->meas_prev = meas;
    double u = k * (err + s->integ + s->deriv);
    int saturated_high = u >= u_max && err > 0.0;
    int saturated_low = u <= u_min && err < 0.0;
    if (!saturated_high && !saturated_low) {
        s->integ += err * dt / ti;
    }
    return k * (err + s->integ + s->deriv);
}

/* Counter-flow heat exchanger effectiveness (epsilon-NTU). */
static double counterflow_effectiveness(double ua, double c_min, double c_max) {
    if (c_min <= 0.0 || ua <= 0.0) return 0.0;
    double ntu = ua / c_min;
    double cr = c_min / c_max;
    if (cr > 1.0 - 1e-9) return ntu / (1.0 + ntu);
    double e = exp(-ntu * (1.0 - cr));
    return (1.0 - e) / (1.0 - cr * e);
}

/* Heat (W) from the hot to the cold stream of a counter-flow exchanger. */
static double hx_heat(double ua, double m_hot, double t_hot_in, double m_cold, double t_cold_in) {
    double c_hot = m_hot * CP_WATER, c_cold = m_cold * CP_WATER;
    double c_min = c_hot < c_cold ? c_hot : c_cold;
    double c_max = c_hot < c_cold ? c_cold : c_hot;
    return counterflow_effectiveness(ua, c_min, c_max) * c_min * (t_hot_in - t_cold_in);
}

/* CDU heat exchanger UA from the two volume flows: each side's film conductance
 * grows as flow^0.8 up to the saturation flow; the sides act in series. */
static double cdu_hx_ua(const Model *m, int i, double m_primary, double m_secondary) {
    double hp = 2.0 * P_HX_UA_SAT * pow(fmin(m_primary / RHO_WATER / P_HX_FLOW_SAT, 1.0), 0.8);
    double hs = 2.0 * P_HX_UA_SAT * pow(fmin(m_secondary / RHO_WATER / P_HX_FLOW_SAT, 1.0), 0.8);
    if (hp <= 0.0 || hs <= 0.0) return 0.0;
    return deviation(m, OFF_IN_DEVIATION_HX_UA + i) * P_HX_UA_CORRECTION / (1.0 / hp + 1.0 / hs);
}

/* Secondary flow (kg/s) where the parallel pumps' curve head = f (a*s^2 - b*q^2) meets
 * the loop's linear resistance dp = R*m (f: the head-curve deviation input, 1 as described). */
static double secondary_flow(const Model *m, int i, double speed) {
    double degradation = clampd(IN(IN_FAULT_PUMP_DEGRADATION, i), 0.0, 0.95);
    double head = deviation(m, OFF_IN_DEVIATION_PUMP_HEAD + i);
    double n = P_CDU_PUMP_N;
    double c = head * RHO_WATER * GRAVITY * speed * speed * P_CDU_PUMP_A * (1.0 - degradation);
    if (c <= 0.0) return 0.0;
    double k = head * GRAVITY * P_CDU_PUMP_B / (RHO_WATER * n * n);
    double r = P_R_HX_SECONDARY + P_R_CABINET;
    return 2.0 * c / (r + sqrt(r * r + 4.0 * k * c));
}

/* Leaving water of an active cell: the Frontier York-type approach correlation
 * (frontier-cooling-physics.md), T_app = 5/9 (c1 + (c2 - 1) T_wb[F]), with
 * c1 = 25 - 0.6 (27 - 17 adj), c2 = 0.73 + 0.0067 (27 - 17 adj), is linear in adj:
 * T_app = alpha + beta adj. We take adj = Q_cell / (Q_design * air ratio), the cell's heat per
 * unit air relative to design; with Q_cell = m c_p (T_in - T_lw) the leaving temperature then
 * has a closed form (no algebraic loop to iterate). */
static double tower_leaving_temp(const Model *m, int n, double t_wet_bulb, double t_in, double air_ratio) {
    double twb_f = fmin((t_wet_bulb - 273.15) * 1.8 + 32.0, P_CT_WB_MAX_F);
    double fit = deviation(m, OFF_IN_DEVIATION_CT_APPROACH + n); /* the plant's cells vs the fit */
    double alpha = fit * 5.0 / 9.0 * (8.8 - 0.0891 * twb_f);
    double beta = fit * 5.0 / 9.0 * (10.2 - 0.1139 * twb_f);
    double gamma = P_CT_CELL_FLOW * CP_WATER / (P_CT_DESIGN_HEAT * air_ratio);
    double t_lw = (t_wet_bulb + alpha + beta * gamma * t_in) / (1.0 + beta * gamma);
    t_lw = fmax(t_lw, t_wet_bulb + P_CT_APPROACH_MIN);
    return fmin(t_lw, t_in);
}

static double stored_energy(const Model *m) {
    double e = 0.0;
    for (int k = 0; k < NBG; k++) e += P_BG_HEAT_CAPACITY * m->t_blade[k];
    for (int i = 0; i < NCAB; i++) {
        e += CP_WATER * (P_HX_VOLUME_KG * m->t_supply[i] + P_CABINET_VOLUME_KG * m->t_return[i]);
    }
    e += CP_WATER * (P_HTW_SUPPLY_KG * m->t_htw_supply + P_HTW_RETURN_KG * m->t_htw_return);
    for (int n = 0; n < NTOW; n++) e += CP_WATER * P_BASIN_KG * m->t_basin[n];
    return e;
}

static int cells_available(const Model *m, int n) {
    int count = 0;
    for (int j = 0; j < NCELL; j++) count += IN(IN_FAULT_CELL_OUT, n * NCELL + j) < 0.5;
    return count;
}

void model_init(Model *m) {
    double sp = P_INIT_SUPPLY_SETPOINT;
    for (int i = 0; i < NCAB; i++) {
        m->t_supply[i] = sp;
        m->t_return[i] = sp + 6.0;
        m->pump_speed[i] = 0.8 * P_CDU_SPEED_MAX;
        m->valve_pos[i] = 0.5;
        memset(&m->dp_pid[i], 0, sizeof(PidState));
        memset(&m->temp_pid[i], 0, sizeof(PidState));
        m->dp_pid[i].integ = m->pump_speed[i] / P_DP_K;
        m->temp_pid[i].integ = m->valve_pos[i] / P_TEMP_K;
        m->dp_pid[i].meas_prev = P_INIT_DP_SETPOINT / PSI_PA;
        m->temp_pid[i].meas_prev = sp;
        m->stuck[i] = 0;
        m->stuck_pos[i] = m->valve_pos[i];
    }
    for (int k = 0; k < NBG; k++) m->t_blade[k] = sp + 8.0;
    m->t_htw_supply = sp - 4.0;
    m->t_htw_return = sp + 2.0;
    for (int n = 0; n < NTOW; n++) {
        m->t_basin[n] = sp - 6.0;
        m->fan_speed[n] = 0.5;
        m->fan_integ[n] = 0.5 / P_FAN_K;
        m->leaving_temp[n] = P_INIT_LW_SETPOINT;
        m->cells_on[n] = NCELL;
        m->stage_up_timer[n] = m->stage_down_timer[n] = 0.0;
    }
    m->time = 0.0;
    m->stored_energy_init = stored_energy(m);
    m->energy_in = m->energy_rejected = m->energy_recovered = 0.0;
}

/* Valve split as applied: fractions clamped to [0, 1] and normalized (equal if all 0). */
static void applied_valve_split(Model *m, int i, double *frac) {
    double total = 0.0;
    for (int j = 0; j < NBR; j++) {
        double v = IN(IN_VALVE_FRACTION, i * NBR + j);
        frac[j] = isfinite(v) ? clampd(v, 0.0, 1.0) : 0.0;
        total += frac[j];
    }
    for (int j = 0; j < NBR; j++) {
        frac[j] = total > 1e-12 ? frac[j] / total : 1.0 / NBR;
        OUT(OUT_APPLIED_VALVE_FRACTION, i * NBR + j) = frac[j];
    }
}

static double finite_or(double x, double fallback) { return isfinite(x) ? x : fallback; }

/* Blade groups over the whole step with the coolant supply held at its start value. */
static double step_blade_groups(Model *m, double h, double *heat_to_coolant, const double (*split)[NBR],
                                double *heat_in_total, double *throttled_total) {
    double it_power = 0.0, heat_in = 0.0, throttled = 0.0;
    const double cap = P_BG_HEAT_CAPACITY;
    for (int i = 0; i < NCAB; i++) {
        double m_sec = secondary_flow(m, i, m->pump_speed[i]);
        double t_in = m->t_supply[i];
        heat_to_coolant[i] = 0.0;
        for (int j = 0; j < NBR; j++) {
            int b = i * NBR + j;
            double m_group = split[i][j] * m_sec / NG;
            double g_eff = 0.0;
            if (m_group > 1e-9) {
                double conductance = P_BG_CONDUCTANCE * pow(m_group / P_BG_FLOW_NOMINAL, P_BG_FLOW_EXPONENT);
                double c_flow = m_group * CP_WATER;
                g_eff = c_flow * (1.0 - exp(-conductance / c_flow));
            }
            double decay = exp(-g_eff * h / cap);
            double branch_power = 0.0, branch_heat = 0.0, sum_t = 0.0, max_t = -1e300;
            for (int g = 0; g < NG; g++) {
                int k = b * NG + g;
                double p = fmax(finite_or(IN(IN_BLADE_POWER, k), 0.0), 0.0);
                double t_old = m->t_blade[k], t_new;
                /* over-temperature blades throttle linearly down to a shutdown */
                double run = clampd((P_SHUTDOWN_TEMP - t_old) / (P_SHUTDOWN_TEMP - P_THROTTLE_START), 0.0, 1.0);
                double q = run * p * (1.0 + P_HEAT_NONLINEARITY * p / P_HEAT_UNIT);
                throttled += (1.0 - run) * p;
                if (g_eff > 1e-9) {
                    double t_eq = t_in + q / g_eff;
                    t_new = t_eq + (t_old - t_eq) * decay;
                } else {
                    t_new = t_old + q * h / cap;
                }
                m->t_blade[k] = t_new;
                OUT(OUT_BLADE_TEMP, k) = t_new;
                branch_power += p;
                branch_heat += q - cap * (t_new - t_old) / h;
                heat_in += q;
                sum_t += t_new;
                if (t_new > max_t) max_t = t_new;
            }
            heat_to_coolant[i] += branch_heat;
            OUT(OUT_BRANCH_TEMP, b) = sum_t / NG;
            OUT(OUT_BRANCH_MAX_TEMP, b) = max_t;
            OUT(OUT_BRANCH_POWER, b) = branch_power;
            OUT(OUT_BRANCH_FLOW, b) = split[i][j] * m_sec;
            it_power += branch_power;
        }
    }
    *heat_in_total = heat_in;
    *throttled_total = throttled;
    return it_power;
}

/* One CDU's inner loops for a sub-step: pump speed on cabinet dp, primary valve on supply temperature. */
static void step_cdu_controls(Model *m, int i, double dt, double dp_sp, double supply_sp) {
    double m_sec = secondary_flow(m, i, m->pump_speed[i]);
    double dp_psi = P_R_CABINET * m_sec / PSI_PA;
    double err = dp_sp / PSI_PA - dp_psi;
    double cmd = pid_update(&m->dp_pid[i], P_DP_K, P_DP_TI, P_DP_TD, err, dp_psi, 1.0, dt, P_CDU_SPEED_MIN,
                            P_CDU_SPEED_MAX);
    cmd = clampd(cmd, P_CDU_SPEED_MIN, P_CDU_SPEED_MAX);
    m->pump_speed[i] += (cmd - m->pump_speed[i]) * fmin(dt / P_PUMP_TAU, 1.0);

    double measured = m->t_supply[i] + finite_or(IN(IN_FAULT_SENSOR_BIAS, i), 0.0);
    double t_err = measured - supply_sp;
    if (fabs(t_err) < P_TEMP_DEADBAND) t_err = 0.0;
    double vcmd = pid_update(&m->temp_pid[i], P_TEMP_K, P_TEMP_TI, P_TEMP_TD, t_err, measured, -1.0, dt,
                             P_VALVE_MIN, 1.0);
    vcmd = clampd(vcmd, P_VALVE_MIN, 1.0);
    int stuck_now = IN(IN_FAULT_VALVE_STUCK, i) > 0.5;
    if (stuck_now && !m->stuck[i]) m->stuck_pos[i] = m->valve_pos[i];
    m->stuck[i] = stuck_now;
    if (m->stuck[i]) {
        m->valve_pos[i] = m->stuck_pos[i];
    } else {
        m->valve_pos[i] += (vcmd - m->valve_pos[i]) * fmin(dt / P_VALVE_TAU, 1.0);
    }
}

/* Tower fan PI and cell staging for a sub-step. */
static void step_tower_controls(Model *m, int n, double dt, double lw_sp) {
    int available = cells_available(m, n);
    if (m->cells_on[n] > available) m->cells_on[n] = available;
    if (m->cells_on[n] < 1 && available > 0) m->cells_on[n] = 1;
    double err = m->leaving_temp[n] - lw_sp; /* too warm -> more fan */
    double u = P_FAN_K * (err + m->fan_integ[n]);
    if (!((u >= 1.0 && err > 0.0) || (u <= 0.0 && err < 0.0))) m->fan_integ[n] += err * dt / P_FAN_TI;
    u = clampd(P_FAN_K * (err + m->fan_integ[n]), 0.0, 1.0);
    m->fan_speed[n] += (u - m->fan_speed[n]) * fmin(dt / P_FAN_TAU, 1.0);

    m->stage_up_timer[n] = m->fan_speed[n] > P_STAGE_UP_SPEED ? m->stage_up_timer[n] + dt : 0.0;
    m->stage_down_timer[n] = m->fan_speed[n] < P_STAGE_DOWN_SPEED ? m->stage_down_timer[n] + dt : 0.0;
    if (m->stage_up_timer[n] >= P_STAGE_DELAY && m->cells_on[n] < available) {
        m->cells_on[n]++;
        m->stage_up_timer[n] = 0.0;
    } else if (m->stage_down_timer[n] >= P_STAGE_DELAY && m->cells_on[n] > 1) {
        m->cells_on[n]--;
        m->stage_down_timer[n] = 0.0;
    }
}

int model_do_step(Model *m, double h) {
    double (*split)[NBR] = (double (*)[NBR])m->valve_split;
    double heat_to_coolant[NCAB];
    double supply_sp[NCAB], dp_sp[NCAB], lw_sp[NTOW];
    double t_wb = clampd(finite_or(IN(IN_WET_BULB, 0), 288.15), 223.15, 323.15);

    for (int i = 0; i < NCAB; i++) {
        supply_sp[i] = clampd(finite_or(IN(IN_SUPPLY_TEMP_SETPOINT, i), P_INIT_SUPPLY_SETPOINT), 283.15, 323.15);
        dp_sp[i] = clampd(finite_or(IN(IN_DP_SETPOINT, i), P_INIT_DP_SETPOINT), 0.0, 1e6);
        OUT(OUT_APPLIED_SUPPLY_SETPOINT, i) = supply_sp[i];
        OUT(OUT_APPLIED_DP_SETPOINT, i) = dp_sp[i];
        applied_valve_split(m, i, split[i]);
    }
    for (int n = 0; n < NTOW; n++) {
        lw_sp[n] = clampd(finite_or(IN(IN_LW_SETPOINT, n), P_INIT_LW_SETPOINT), 273.65, 323.15);
        OUT(OUT_APPLIED_LW_SETPOINT, n) = lw_sp[n];
    }

    double heat_in = 0.0, throttled = 0.0;
    double it_power = step_blade_groups(m, h, heat_to_coolant, (const double (*)[NBR])split, &heat_in, &throttled);

    int nsub = (int)ceil(h / (STEP_S / NSUB) - 1e-9);
    if (nsub < 1) nsub = 1;
    double dt = h / nsub;

    /* step means */
    double sum_cdu_heat[NCAB] = {0}, sum_cdu_pump[NCAB] = {0}, sum_primary_out[NCAB] = {0};
    double sum_ehx[NTOW] = {0}, sum_ct_in[NTOW] = {0}, sum_ct_pump[NTOW] = {0}, sum_approach[NTOW] = {0};
    double sum_cell_fan[NTOW * NCELL] = {0}, sum_cell_heat[NTOW * NCELL] = {0};
    double sum_htw_flow = 0.0, sum_htw_pump = 0.0, sum_rejected = 0.0, sum_recovered = 0.0;
    double sum_district_out = 0.0;
    double t_primary_out[NCAB];

    for (int s = 0; s < nsub; s++) {
        /* 1. fluxes from the states at the start of the sub-step */
        double primary_total = 0.0, primary_enthalpy = 0.0;
        double d_supply[NCAB], d_return[NCAB];
        for (int i = 0; i < NCAB; i++) {
            double ms = secondary_flow(m, i, m->pump_speed[i]);
            double mp = m->valve_pos[i] * P_PRIMARY_FLOW_MAX;
            double ua = cdu_hx_ua(m, i, mp, ms);
            double q = hx_heat(ua, ms, m->t_return[i], mp, m->t_htw_supply);
            double t_sec_out = ms > 0.0 ? m->t_return[i] - q / (ms * CP_WATER) : m->t_return[i];
            t_primary_out[i] = mp > 0.0 ? m->t_htw_supply + q / (mp * CP_WATER) : m->t_htw_supply;
            d_supply[i] = dt * ms * CP_WATER * (t_sec_out - m->t_supply[i]);
            d_return[i] = dt * (ms * CP_WATER * (m->t_supply[i] - m->t_return[i]) + heat_to_coolant[i]);
            primary_total += mp;
            primary_enthalpy += mp * CP_WATER * t_primary_out[i];
            double dp_pump = (P_R_HX_SECONDARY + P_R_CABINET) * ms;
            sum_cdu_heat[i] += q;
            sum_cdu_pump[i] += dp_pump * ms / (RHO_WATER * P_CDU_PUMP_ETA);
            sum_primary_out[i] += t_primary_out[i];
        }
        double m_htw = fmax(P_HTW_FLOW_MIN, (1.0 + P_HTW_BYPASS) * primary_total);
        double m_bypass = m_htw - primary_total;
        double d_htw_return =
            dt * (primary_enthalpy + m_bypass * CP_WATER * m->t_htw_supply - m_htw * CP_WATER * m->t_htw_return);
        double htw_dp = P_HTW_CDU_DP + P_HTW_R_HEADER * m_htw;
        sum_htw_flow += m_htw;
        sum_htw_pump += htw_dp * m_htw / (RHO_WATER * P_HTW_PUMP_ETA);

        double t_after_hru = m->t_htw_return;
        if (HAS_HRU && IN(IN_HRU_ENABLE, 0) > 0.5) {
            double q_hru = fmax(0.0, hx_heat(P_HRU_UA, m_htw, m->t_htw_return, P_HRU_FLOW, P_HRU_TEMP));
            t_after_hru -= q_hru / (m_htw * CP_WATER);
            sum_recovered += q_hru;
            sum_district_out += P_HRU_TEMP + q_hru / (P_HRU_FLOW * CP_WATER);
        } else {
            sum_district_out += P_HRU_TEMP;
        }

        double m_train = m_htw / NTOW, htw_supply_in = 0.0, d_basin[NTOW];
        for (int n = 0; n < NTOW; n++) {
            int on = m->cells_on[n];
            double m_ct = on * P_CT_CELL_FLOW;
            double q_ehx = m_ct > 0.0 ? hx_heat(P_EHX_UA, m_train, t_after_hru, m_ct, m->t_basin[n]) : 0.0;
            htw_supply_in += m_train * CP_WATER * t_after_hru - q_ehx;
            double t_ct_in = m_ct > 0.0 ? m->t_basin[n] + q_ehx / (m_ct * CP_WATER) : m->t_basin[n];
            /* every active cell runs at the tower's fan speed and sees the same inlet */
            double air = fmax(m->fan_speed[n], P_CT_FREE_CONVECTION);
            double t_lw = tower_leaving_temp(m, n, t_wb, t_ct_in, air);
            double q_cell = P_CT_CELL_FLOW * CP_WATER * (t_ct_in - t_lw);
            m->leaving_temp[n] = on > 0 ? t_lw : t_ct_in;
            int placed = 0;
            for (int j = 0; j < NCELL; j++) {
                int c = n * NCELL + j;
                int active = IN(IN_FAULT_CELL_OUT, c) < 0.5 && placed < on;
                placed += active;
                if (active) {
                    double sp3 = m->fan_speed[n] * m->fan_speed[n] * m->fan_speed[n];
                    sum_cell_fan[c] += P_CT_FAN_NOMINAL * sp3;
                    sum_cell_heat[c] += q_cell;
                }
            }
            sum_rejected += on * q_cell;
            sum_ehx[n] += q_ehx;
            sum_ct_in[n] += t_ct_in;
            sum_approach[n] += t_lw - t_wb;
            sum_ct_pump[n] += on * GRAVITY * P_CT_PUMP_HEAD * P_CT_CELL_FLOW / P_CT_PUMP_ETA;
            d_basin[n] = dt * m_ct * CP_WATER * (t_lw - m->t_basin[n]);
        }
        double d_htw_supply = dt * (htw_supply_in - m_htw * CP_WATER * m->t_htw_supply);

        /* 2. states */
        for (int i = 0; i < NCAB; i++) {
            m->t_supply[i] += d_supply[i] / (P_HX_VOLUME_KG * CP_WATER);
            m->t_return[i] += d_return[i] / (P_CABINET_VOLUME_KG * CP_WATER);
        }
        m->t_htw_return += d_htw_return / (P_HTW_RETURN_KG * CP_WATER);
        m->t_htw_supply += d_htw_supply / (P_HTW_SUPPLY_KG * CP_WATER);
        for (int n = 0; n < NTOW; n++) m->t_basin[n] += d_basin[n] / (P_BASIN_KG * CP_WATER);

        /* 3. controllers act on the new measurements */
        for (int i = 0; i < NCAB; i++) step_cdu_controls(m, i, dt, dp_sp[i], supply_sp[i]);
        for (int n = 0; n < NTOW; n++) step_tower_controls(m, n, dt, lw_sp[n]);
    }

    /* outputs: temperatures at the end of the step, powers as step means */
    double inv = 1.0 / nsub;
    double it_cooling = 0.0, pump_power = 0.0, fan_power = 0.0;
    for (int i = 0; i < NCAB; i++) {
        double ms = secondary_flow(m, i, m->pump_speed[i]);
        OUT(OUT_SUPPLY_TEMP, i) = m->t_supply[i];
        OUT(OUT_SUPPLY_TEMP_MEASURED, i) = m->t_supply[i] + finite_or(IN(IN_FAULT_SENSOR_BIAS, i), 0.0);
        OUT(OUT_RETURN_TEMP, i) = m->t_return[i];
        OUT(OUT_SECONDARY_FLOW, i) = ms;
        OUT(OUT_CABINET_DP, i) = P_R_CABINET * ms;
        OUT(OUT_PUMP_SPEED, i) = m->pump_speed[i];
        OUT(OUT_CDU_PUMP_POWER, i) = sum_cdu_pump[i] * inv;
        OUT(OUT_PRIMARY_VALVE, i) = m->valve_pos[i];
        OUT(OUT_PRIMARY_FLOW, i) = m->valve_pos[i] * P_PRIMARY_FLOW_MAX;
        OUT(OUT_PRIMARY_RETURN_TEMP, i) = sum_primary_out[i] * inv;
        OUT(OUT_CDU_HEAT, i) = sum_cdu_heat[i] * inv;
        it_cooling += sum_cdu_heat[i] * inv;
        pump_power += sum_cdu_pump[i] * inv;
    }
    OUT(OUT_HTW_SUPPLY_TEMP, 0) = m->t_htw_supply;
    OUT(OUT_HTW_RETURN_TEMP, 0) = m->t_htw_return;
    OUT(OUT_HTW_FLOW, 0) = sum_htw_flow * inv;
    OUT(OUT_HTW_PUMP_POWER, 0) = sum_htw_pump * inv;
    pump_power += sum_htw_pump * inv;
    for (int n = 0; n < NTOW; n++) {
        OUT(OUT_EHX_HEAT, n) = sum_ehx[n] * inv;
        OUT(OUT_CT_WATER_FLOW, n) = m->cells_on[n] * P_CT_CELL_FLOW;
        OUT(OUT_CT_ENTERING_TEMP, n) = sum_ct_in[n] * inv;
        OUT(OUT_CT_LEAVING_TEMP, n) = m->leaving_temp[n];
        OUT(OUT_CT_BASIN_TEMP, n) = m->t_basin[n];
        OUT(OUT_FAN_SPEED, n) = m->fan_speed[n];
        OUT(OUT_CELLS_ACTIVE, n) = m->cells_on[n];
        OUT(OUT_CT_PUMP_POWER, n) = sum_ct_pump[n] * inv;
        OUT(OUT_APPROACH, n) = sum_approach[n] * inv;
        pump_power += sum_ct_pump[n] * inv;
        for (int j = 0; j < NCELL; j++) {
            int c = n * NCELL + j;
            OUT(OUT_CELL_FAN_POWER, c) = sum_cell_fan[c] * inv;
            OUT(OUT_CELL_HEAT, c) = sum_cell_heat[c] * inv;
            fan_power += sum_cell_fan[c] * inv;
        }
    }
    double rejected = sum_rejected * inv, recovered = sum_recovered * inv;
    double stored_now = stored_energy(m);
    double stored_prev = OUT(OUT_STORED_ENERGY, 0);
    m->energy_in += heat_in * h;
    m->energy_rejected += rejected * h;
    m->energy_recovered += recovered * h;
    OUT(OUT_HEAT_IN, 0) = heat_in;
    OUT(OUT_HEAT_REJECTED, 0) = rejected;
    OUT(OUT_HEAT_RECOVERED, 0) = recovered;
    OUT(OUT_DISTRICT_RETURN_TEMP, 0) = sum_district_out * inv;
    OUT(OUT_STORED_ENERGY_RATE, 0) = (stored_now - stored_prev) / h;
    OUT(OUT_STORED_ENERGY, 0) = stored_now;
    OUT(OUT_STORED_ENERGY_CHANGE, 0) = stored_now - m->stored_energy_init;
    OUT(OUT_ENERGY_IN, 0) = m->energy_in;
    OUT(OUT_ENERGY_REJECTED, 0) = m->energy_rejected;
    OUT(OUT_ENERGY_RECOVERED, 0) = m->energy_recovered;
    OUT(OUT_CT_FAN_POWER_TOTAL, 0) = fan_power;
    OUT(OUT_PUMP_POWER_TOTAL, 0) = pump_power;
    OUT(OUT_IT_COOLING, 0) = it_cooling;
    OUT(OUT_IT_POWER, 0) = it_power;
    OUT(OUT_THROTTLED_POWER, 0) = throttled;
    m->time += h;
    return isfinite(stored_now) ? 0 : 1;
}

/* Fill every output from the current state (after initialization, before any step). */
void model_outputs_at_init(Model *m) {
    for (int i = 0; i < NCAB; i++) {
        double ms = secondary_flow(m, i, m->pump_speed[i]);
        OUT(OUT_SUPPLY_TEMP, i) = m->t_supply[i];
        OUT(OUT_SUPPLY_TEMP_MEASURED, i) = m->t_supply[i];
        OUT(OUT_RETURN_TEMP, i) = m->t_return[i];
        OUT(OUT_SECONDARY_FLOW, i) = ms;
        OUT(OUT_CABINET_DP, i) = P_R_CABINET * ms;
        OUT(OUT_PUMP_SPEED, i) = m->pump_speed[i];
        OUT(OUT_PRIMARY_VALVE, i) = m->valve_pos[i];
    }
    for (int k = 0; k < NBG; k++) OUT(OUT_BLADE_TEMP, k) = m->t_blade[k];
    for (int b = 0; b < NCAB * NBR; b++) OUT(OUT_BRANCH_TEMP, b) = OUT(OUT_BRANCH_MAX_TEMP, b) = m->t_blade[b * NG];
    OUT(OUT_HTW_SUPPLY_TEMP, 0) = m->t_htw_supply;
    OUT(OUT_HTW_RETURN_TEMP, 0) = m->t_htw_return;
    for (int n = 0; n < NTOW; n++) {
        OUT(OUT_CT_BASIN_TEMP, n) = m->t_basin[n];
        OUT(OUT_CT_LEAVING_TEMP, n) = m->leaving_temp[n];
        OUT(OUT_FAN_SPEED, n) = m->fan_speed[n];
        OUT(OUT_CELLS_ACTIVE, n) = m->cells_on[n];
    }
    OUT(OUT_STORED_ENERGY, 0) = m->stored_energy_init;
}
