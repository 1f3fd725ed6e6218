//! The simulation trace: one row per trace period with every state, measurement, estimate and
//! actuator, written as `trace.csv`.

/// Most trajectory points the map draws: a longer trace is drawn from every n-th row
/// (the map of `plot/` draws it; the streaming trace keeps the same rows).
pub const MAX_TRAJ_POINTS: usize = 20_000;

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

impl TraceRow {
    /// The row of `values` in column order (the inverse of [`TraceRow::values`]).
    pub fn from_values(v: [f64; 33]) -> TraceRow {
        let [t_s, m_kg_s, flow_map, p_suction_pa, p_discharge_pa, pressure_ratio, omega_rad_s, recycle_flow_kg_s, throttle_flow_kg_s, feed_flow_kg_s, recycle_valve_position, throttle_position, drive_torque_nm, load_torque_nm, ccv, tip_clearance_m, thrust_force_n, thrust_slew_n_s, surge_margin, meas_p_suction_pa, meas_p_discharge_pa, meas_omega_rad_s, meas_orifice_dp_pa, meas_m_kg_s, est_m_kg_s, used_m_kg_s, cmd_drive_torque_nm, cmd_recycle_valve, cmd_ccv, cmd_throttle, cmd_tip_clearance_m, mode, law_diagnostic] =
            v;
        TraceRow {
            t_s,
            m_kg_s,
            flow_map,
            p_suction_pa,
            p_discharge_pa,
            pressure_ratio,
            omega_rad_s,
            recycle_flow_kg_s,
            throttle_flow_kg_s,
            feed_flow_kg_s,
            recycle_valve_position,
            throttle_position,
            drive_torque_nm,
            load_torque_nm,
            ccv,
            tip_clearance_m,
            thrust_force_n,
            thrust_slew_n_s,
            surge_margin,
            meas_p_suction_pa,
            meas_p_discharge_pa,
            meas_omega_rad_s,
            meas_orifice_dp_pa,
            meas_m_kg_s,
            est_m_kg_s,
            used_m_kg_s,
            cmd_drive_torque_nm,
            cmd_recycle_valve,
            cmd_ccv,
            cmd_throttle,
            cmd_tip_clearance_m,
            mode,
            law_diagnostic,
        }
    }
}

/// One CSV line of `r` into `line` (cleared first; NaN written as an empty field, no newline).
fn format_row(line: &mut String, r: &TraceRow, volumetric: bool) {
    use std::fmt::Write as _;
    line.clear();
    for (i, v) in r.values().iter().enumerate() {
        if i > 0 {
            line.push(',');
        }
        if v.is_finite() {
            let _ = write!(line, "{v:.7e}");
        }
    }
    line.push(',');
    line.push(if volumetric { '1' } else { '0' });
    line.push('\n');
}

/// Write rows as CSV (NaN written as empty fields): the whole trace of a run kept in memory.
/// [`CsvTraceWriter`] writes the same bytes a row at a time.
pub fn write_csv(out: &mut impl Write, rows: &[TraceRow], volumetric: bool) -> std::io::Result<()> {
    writeln!(out, "{}", COLUMNS.join(","))?;
    let mut line = String::with_capacity(LINE_CAPACITY);
    for r in rows {
        format_row(&mut line, r, volumetric);
        out.write_all(line.as_bytes())?;
    }
    Ok(())
}

/// Room for one CSV line: 33 fields of at most 15 characters (`-1.2345678e-100`), commas, the
/// unit flag and the newline.
const LINE_CAPACITY: usize = 34 * 16 + 2;

/// Bytes the trace file's writer holds before it writes them out: a few hundred rows.
pub const CSV_BUFFER_BYTES: usize = 1 << 16;

/// `trace.csv` written as the run goes (`antisurge sim`): the bytes of [`write_csv`], through a
/// buffer of [`CSV_BUFFER_BYTES`], so a run of any length holds one buffer of the trace, never
/// the trace. Writing a row does not allocate. The first write error is kept (later rows are
/// dropped) and returned by [`CsvTraceWriter::finish`], so the simulation loop never stops on
/// the file system's account.
pub struct CsvTraceWriter<W: Write> {
    out: std::io::BufWriter<W>,
    line: String,
    volumetric: bool,
    rows: u64,
    error: Option<std::io::Error>,
}

impl<W: Write> CsvTraceWriter<W> {
    /// A writer to `out`; writes the header line at once. `volumetric`: the map's flow
    /// coordinate is inlet volume flow (the last column).
    pub fn new(out: W, volumetric: bool) -> Self {
        let mut out = std::io::BufWriter::with_capacity(CSV_BUFFER_BYTES, out);
        let error = writeln!(out, "{}", COLUMNS.join(",")).err();
        CsvTraceWriter {
            out,
            line: String::with_capacity(LINE_CAPACITY),
            volumetric,
            rows: 0,
            error,
        }
    }

    /// Write one row.
    pub fn push(&mut self, r: &TraceRow) {
        if self.error.is_some() {
            return;
        }
        format_row(&mut self.line, r, self.volumetric);
        match self.out.write_all(self.line.as_bytes()) {
            Ok(()) => self.rows += 1,
            Err(e) => self.error = Some(e),
        }
    }

    /// Write out the rows held in the buffer: whole lines (the buffer holds whole lines and
    /// is written out whole), so a reader of complete lines sees no torn row. An error is kept as
    /// [`CsvTraceWriter::push`]'s are.
    pub fn flush(&mut self) {
        if self.error.is_none() {
            self.error = self.out.flush().err();
        }
    }

    /// Rows written so far.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Flush the buffer; the first error of the run, if any.
    pub fn finish(mut self) -> std::io::Result<W> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        self.out.into_inner().map_err(|e| e.into_error())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(k: usize) -> TraceRow {
        let mut v = [0.0; 33];
        for (i, x) in v.iter_mut().enumerate() {
            *x = (k * 33 + i) as f64 * 1.234_567_891e-3 - 7.0;
        }
        v[4] = f64::NAN;
        v[9] = f64::INFINITY;
        TraceRow::from_values(v)
    }

    #[test]
    fn from_values_inverts_values() {
        let r = row(3);
        let back = TraceRow::from_values(r.values());
        assert_eq!(
            back.values().map(f64::to_bits),
            r.values().map(f64::to_bits)
        );
    }

    #[test]
    fn streamed_csv_is_the_bytes_of_the_whole_trace() {
        let rows: Vec<TraceRow> = (0..2000).map(row).collect();
        for volumetric in [false, true] {
            let mut whole = Vec::new();
            write_csv(&mut whole, &rows, volumetric).expect("write");
            let mut w = CsvTraceWriter::new(Vec::new(), volumetric);
            for r in &rows {
                w.push(r);
            }
            assert_eq!(w.rows(), 2000);
            let streamed = w.finish().expect("finish");
            assert_eq!(streamed, whole);
            let text = String::from_utf8(whole).expect("utf8");
            assert!(
                text.lines().nth(1).expect("row").contains(",,"),
                "NaN is an empty field"
            );
        }
    }

    /// A sink that fails after `ok` bytes.
    struct Full {
        ok: usize,
    }
    impl Write for Full {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            if self.ok == 0 {
                return Err(std::io::Error::other("disk full"));
            }
            let n = b.len().min(self.ok);
            self.ok -= n;
            Ok(n)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_write_error_is_kept_and_returned_at_the_end() {
        let mut w = CsvTraceWriter::new(Full { ok: 100_000 }, false);
        for k in 0..2000 {
            w.push(&row(k));
        }
        let e = w.finish().err().expect("the error");
        assert_eq!(e.to_string(), "disk full");
    }
}
