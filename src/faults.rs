//! The DBC value table of the fault word (the field faults the I/O tasks raise are counted in
//! [`crate::io::link::FieldFaults`]). The vocabulary itself (the fault categories, the fault word, the
//! kinds of field link) is on the ground floor, [`crate::vocab::faults`].

use crate::vocab::faults::FaultCategory;

/// The DBC `VAL_` entries of a `Faults` signal: one value per single-bit word
/// (`1 "sensor_timeout" 2 "sensor_alive_error" …`), for message `id` and `signal`.
pub fn dbc_value_table(id: u32, signal: &str) -> String {
    let mut s = format!("VAL_ {id} {signal} 0 \"healthy\"");
    for c in FaultCategory::ALL {
        s += &format!(" {} \"{}\"", c.bit(), c.name());
    }
    s + " ;"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_dbc_documents_this_vocabulary() {
        let dbc = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/skid.dbc"),
        )
        .expect("skid.dbc");
        assert!(
            dbc.contains(&dbc_value_table(128, "Faults")),
            "config/skid.dbc must carry: {}",
            dbc_value_table(128, "Faults")
        );
        for c in FaultCategory::ALL {
            assert!(
                dbc.contains(&format!("bit {} {}", c.code(), c.name())),
                "{}",
                c.name()
            );
        }
    }

    #[test]
    fn value_table_lists_every_category() {
        let t = dbc_value_table(128, "Faults");
        assert!(t.starts_with("VAL_ 128 Faults 0 \"healthy\" 1 \"sensor_timeout\""));
        assert!(t.contains("256 \"actuator_feedback_mismatch\""));
        assert!(t.ends_with(" ;"));
    }
}
