//! The simulation trace: one row per trace period with every state, measurement, estimate and
//! actuator, written as `trace.csv`.

use std::io::Write;

/// One trace row (SI units; NaN where a plant has no such quantity).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TraceRow {
    /// Time, s.
    pub t_s: f64,
    // true plant state
    /// Compressor mass flow, kg/s.
    pub m_kg_s: f64,
    /// Flow in map coordinates.
    pub flow_map: f64,
    /// Suction pressure, Pa.
    pub p_suction_pa: f64,
    /// Discharge pressure, Pa.
    pub p_discharge_pa: f64,
    /// Pressure ratio.
    pub pressure_ratio: f64,
    /// Shaft speed, rad/s.
    pub omega_rad_s: f64,
    /// Recycle flow, kg/s.
    pub recycle_flow_kg_s: f64,
    /// Throttle flow, kg/s.
    pub throttle_flow_kg_s: f64,
    /// Feed flow, kg/s.
    pub feed_flow_kg_s: f64,
    /// Recycle valve position.
    pub recycle_valve_position: f64,
    /// Throttle position.
    pub throttle_position: f64,
    /// Drive torque delivered, N·m.
    pub drive_torque_nm: f64,
    /// Load torque, N·m.
    pub load_torque_nm: f64,
    /// Close-coupled valve applied.
    pub ccv: f64,
    /// Tip-clearance change, m.
    pub tip_clearance_m: f64,
    /// Thrust force, N.
    pub thrust_force_n: f64,
    /// Thrust force slew, N/s.
    pub thrust_slew_n_s: f64,
    /// Surge margin (q − q_SL)/q_SL of the true state.
    pub surge_margin: f64,
    // measured and estimated
    /// Measured suction pressure (with noise/faults), Pa.
    pub meas_p_suction_pa: f64,
    /// Measured discharge pressure, Pa.
    pub meas_p_discharge_pa: f64,
    /// Measured speed, rad/s.
    pub meas_omega_rad_s: f64,
    /// Measured orifice Δp, Pa.
    pub meas_orifice_dp_pa: f64,
    /// Flow from the orifice measurement, kg/s.
    pub meas_m_kg_s: f64,
    /// Observer estimate, kg/s.
    pub est_m_kg_s: f64,
    /// Flow the laws used, kg/s.
    pub used_m_kg_s: f64,
    // commands
    /// Drive torque command, N·m.
    pub cmd_drive_torque_nm: f64,
    /// Recycle valve command.
    pub cmd_recycle_valve: f64,
    /// Close-coupled valve command.
    pub cmd_ccv: f64,
    /// Throttle command.
    pub cmd_throttle: f64,
    /// Tip-clearance command, m.
    pub cmd_tip_clearance_m: f64,
    /// Controller mode code (0 init, 1 manual, 2 auto, 3 fail-safe).
    pub mode: f64,
    /// Law diagnostic (e.g. control variable z).
    pub law_diagnostic: f64,
}

/// Column names, in the order of [`TraceRow::values`].
pub const COLUMNS: [&str; 34] = [
    "t_s",
    "m_kg_s",
    "flow_map",
    "p_suction_pa",
    "p_discharge_pa",
    "pressure_ratio",
    "omega_rad_s",
    "recycle_flow_kg_s",
    "throttle_flow_kg_s",
    "feed_flow_kg_s",
    "recycle_valve_position",
    "throttle_position",
    "drive_torque_nm",
    "load_torque_nm",
    "ccv",
    "tip_clearance_m",
    "thrust_force_n",
    "thrust_slew_n_s",
    "surge_margin",
    "meas_p_suction_pa",
    "meas_p_discharge_pa",
    "meas_omega_rad_s",
    "meas_orifice_dp_pa",
    "meas_m_kg_s",
    "est_m_kg_s",
    "used_m_kg_s",
    "cmd_drive_torque_nm",
    "cmd_recycle_valve",
    "cmd_ccv",
    "cmd_throttle",
    "cmd_tip_clearance_m",
    "mode",
    "law_diagnostic",
    "flow_map_unit_is_m3_s",
];

impl TraceRow {
    /// Values in column order (the last column is filled by the writer).
    pub fn values(&self) -> [f64; 33] {
        [
            self.t_s,
            self.m_kg_s,
            self.flow_map,
            self.p_suction_pa,
            self.p_discharge_pa,
            self.pressure_ratio,
            self.omega_rad_s,
            self.recycle_flow_kg_s,
            self.throttle_flow_kg_s,
            self.feed_flow_kg_s,
            self.recycle_valve_position,
            self.throttle_position,
            self.drive_torque_nm,
            self.load_torque_nm,
            self.ccv,
            self.tip_clearance_m,
            self.thrust_force_n,
            self.thrust_slew_n_s,
            self.surge_margin,
            self.meas_p_suction_pa,
            self.meas_p_discharge_pa,
            self.meas_omega_rad_s,
            self.meas_orifice_dp_pa,
            self.meas_m_kg_s,
            self.est_m_kg_s,
            self.used_m_kg_s,
            self.cmd_drive_torque_nm,
            self.cmd_recycle_valve,
            self.cmd_ccv,
            self.cmd_throttle,
            self.cmd_tip_clearance_m,
            self.mode,
            self.law_diagnostic,
        ]
    }
}

/// Write rows as CSV (NaN written as empty fields).
pub fn write_csv(out: &mut impl Write, rows: &[TraceRow], volumetric: bool) -> std::io::Result<()> {
    writeln!(out, "{}", COLUMNS.join(","))?;
    let mut line = String::with_capacity(512);
    for r in rows {
        line.clear();
        for (i, v) in r.values().iter().enumerate() {
            if i > 0 {
                line.push(',');
            }
            if v.is_finite() {
                use std::fmt::Write as _;
                let _ = write!(line, "{v:.7e}");
            }
        }
        line.push(',');
        line.push(if volumetric { '1' } else { '0' });
        writeln!(out, "{line}")?;
    }
    Ok(())
}
