//! Request plans: bindings grouped into as few Modbus requests as possible, computed once.
//!
//! A [`ReadPlan`] merges bindings of the same unit id and table whose register ranges touch or
//! overlap into one read request (at most [`MAX_READ_REGISTERS`] registers). Gaps are never
//! bridged: an unmapped register inside a request would make the device answer with an
//! exception for the whole request. A [`WritePlan`] does the same for holding-register writes
//! (at most [`MAX_WRITE_REGISTERS`] per request) and refuses overlapping bindings.

use std::ops::Range;

use thiserror::Error;

use super::register::{find_overlaps, BindingError, RegisterBinding, RegisterTable};

/// Most registers one read request (function 0x03/0x04) may ask for (Modbus spec).
pub const MAX_READ_REGISTERS: u16 = 125;
/// Most registers one write-multiple request (function 0x10) may carry (Modbus spec).
pub const MAX_WRITE_REGISTERS: u16 = 123;
/// Most bits one read-coils / read-discrete-inputs request (0x01/0x02) may ask for (spec).
pub const MAX_READ_BITS: u16 = 2000;
/// Most coils one write-multiple-coils request (0x0F) may carry (Modbus spec).
pub const MAX_WRITE_BITS: u16 = 1968;

/// Largest request in `table`: registers for register tables, bits for bit tables.
pub const fn max_count(table: RegisterTable, read: bool) -> u16 {
    match (table.is_bits(), read) {
        (false, true) => MAX_READ_REGISTERS,
        (false, false) => MAX_WRITE_REGISTERS,
        (true, true) => MAX_READ_BITS,
        (true, false) => MAX_WRITE_BITS,
    }
}

/// One Modbus request of a plan: a contiguous register range of one unit and table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlannedRequest {
    /// Unit (slave) id.
    pub unit_id: u8,
    /// Register table.
    pub table: RegisterTable,
    /// First 0-based protocol address.
    pub address: u16,
    /// Number of registers.
    pub count: u16,
    /// Positions in the plan's member list (bindings covered by this request).
    members: Range<usize>,
    /// For write plans: offset of this request's words in the flat word buffer.
    word_offset: usize,
}

/// Why a plan could not be built.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlanError {
    /// A binding failed [`RegisterBinding::validate`].
    #[error("binding #{index}: {source}")]
    InvalidBinding {
        /// Index of the binding in the list given.
        index: usize,
        /// What is wrong with it.
        source: BindingError,
    },
    /// A write binding points at the input or discrete-input table, which clients cannot
    /// write.
    #[error("binding #{index} is in the {} table, which is read-only", table.name())]
    ReadOnlyTable {
        /// Index of the binding in the list given.
        index: usize,
        /// The read-only table.
        table: RegisterTable,
    },
    /// Two write bindings share registers.
    #[error("write bindings #{first} and #{second} overlap")]
    Overlap {
        /// Index of one binding.
        first: usize,
        /// Index of the other.
        second: usize,
    },
}

/// Group bindings (indices sorted by unit, table, address) into requests of at most
/// [`max_count`] registers or bits, merging ranges that touch or overlap. `merge = false`
/// gives every binding its own request.
fn group_with(
    bindings: &[RegisterBinding],
    read: bool,
    merge: bool,
) -> (Vec<usize>, Vec<PlannedRequest>) {
    let mut order: Vec<usize> = (0..bindings.len()).collect();
    order.sort_by_key(|&i| {
        let b = &bindings[i];
        (b.unit_id, b.table, b.address)
    });
    let mut requests: Vec<PlannedRequest> = Vec::new();
    let mut word_offset = 0usize;
    for (pos, &i) in order.iter().enumerate() {
        let b = &bindings[i];
        if let Some(last) = requests.last_mut() {
            let start = u32::from(last.address);
            let end = start + u32::from(last.count);
            let new_end = end.max(b.end_address());
            if merge
                && last.unit_id == b.unit_id
                && last.table == b.table
                && u32::from(b.address) <= end
                && new_end - start <= u32::from(max_count(b.table, read))
            {
                word_offset += (new_end - end) as usize;
                last.count = (new_end - start) as u16;
                last.members.end = pos + 1;
                continue;
            }
        }
        requests.push(PlannedRequest {
            unit_id: b.unit_id,
            table: b.table,
            address: b.address,
            count: b.register_count(),
            members: pos..pos + 1,
            word_offset,
        });
        word_offset += b.register_count() as usize;
    }
    (order, requests)
}

fn validate_all(bindings: &[RegisterBinding]) -> Result<(), PlanError> {
    for (index, b) in bindings.iter().enumerate() {
        b.validate()
            .map_err(|source| PlanError::InvalidBinding { index, source })?;
    }
    Ok(())
}

/// Bindings to read each cycle, grouped into requests. Values come back in the order the
/// bindings were given.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadPlan {
    bindings: Vec<RegisterBinding>,
    order: Vec<usize>,
    requests: Vec<PlannedRequest>,
}

impl ReadPlan {
    /// Validate the bindings and group them. Overlapping bindings are allowed (the same
    /// registers may be decoded twice, e.g. as raw and scaled values).
    pub fn new(bindings: &[RegisterBinding]) -> Result<ReadPlan, PlanError> {
        validate_all(bindings)?;
        let (order, requests) = group_with(bindings, true, true);
        Ok(ReadPlan {
            bindings: bindings.to_vec(),
            order,
            requests,
        })
    }

    /// The bindings, in the order given (the order of values in a read).
    pub fn bindings(&self) -> &[RegisterBinding] {
        &self.bindings
    }

    /// Number of bindings (length of the value slice a read fills).
    pub fn len(&self) -> usize {
        self.bindings.len()
    }

    /// Whether the plan reads nothing.
    pub fn is_empty(&self) -> bool {
        self.bindings.is_empty()
    }

    /// The requests a read issues, sorted by unit, table, address.
    pub fn requests(&self) -> &[PlannedRequest] {
        &self.requests
    }

    /// Indices (into [`bindings`](Self::bindings)) of the bindings a request covers.
    pub fn members(&self, request: &PlannedRequest) -> &[usize] {
        &self.order[request.members.clone()]
    }
}

/// Bindings to write each cycle, grouped into write-multiple requests. All bindings must be
/// holding registers or coils and must not overlap.
#[derive(Debug, Clone, PartialEq)]
pub struct WritePlan {
    bindings: Vec<RegisterBinding>,
    order: Vec<usize>,
    requests: Vec<PlannedRequest>,
    total_words: usize,
}

impl WritePlan {
    /// Validate the bindings and group them.
    pub fn new(bindings: &[RegisterBinding]) -> Result<WritePlan, PlanError> {
        Self::build(bindings, true)
    }

    /// Validate the bindings and give each its own request, never merging unrelated
    /// registers into one write (a device refuses a write that spans a register it does
    /// not have, and a watchdog register must not ride on a setpoint's request).
    pub fn separate(bindings: &[RegisterBinding]) -> Result<WritePlan, PlanError> {
        Self::build(bindings, false)
    }

    fn build(bindings: &[RegisterBinding], merge: bool) -> Result<WritePlan, PlanError> {
        validate_all(bindings)?;
        if let Some(index) = bindings.iter().position(|b| !b.table.is_writable()) {
            return Err(PlanError::ReadOnlyTable {
                index,
                table: bindings[index].table,
            });
        }
        if let Some(o) = find_overlaps(bindings).first() {
            return Err(PlanError::Overlap {
                first: o.first,
                second: o.second,
            });
        }
        let (order, requests) = group_with(bindings, false, merge);
        let total_words = requests.iter().map(|r| r.count as usize).sum();
        Ok(WritePlan {
            bindings: bindings.to_vec(),
            order,
            requests,
            total_words,
        })
    }

    /// The bindings, in the order given (the order of values in a write).
    pub fn bindings(&self) -> &[RegisterBinding] {
        &self.bindings
    }

    /// Number of bindings (length of the value slice a write takes).
    pub fn len(&self) -> usize {
        self.bindings.len()
    }

    /// Whether the plan writes nothing.
    pub fn is_empty(&self) -> bool {
        self.bindings.is_empty()
    }

    /// The largest set of requests a write issues (when no value is NaN).
    pub fn requests(&self) -> &[PlannedRequest] {
        &self.requests
    }

    /// Indices (into [`bindings`](Self::bindings)) of the bindings a request covers, in
    /// address order.
    pub fn members(&self, request: &PlannedRequest) -> &[usize] {
        &self.order[request.members.clone()]
    }

    /// Registers of all requests together (size of the client's encode buffer).
    pub(crate) fn total_words(&self) -> usize {
        self.total_words
    }

    /// Offset of a request's words in the flat encode buffer.
    pub(crate) fn word_offset(request: &PlannedRequest) -> usize {
        request.word_offset
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::modbus::register::DataType;
    use RegisterTable::{Holding, Input};

    fn rb(unit: u8, table: RegisterTable, address: u16, dt: DataType) -> RegisterBinding {
        RegisterBinding::new(unit, table, address, dt)
    }

    #[test]
    fn contiguous_bindings_share_one_request() {
        let list = [
            rb(1, Input, 4, DataType::F32),   // 4..6
            rb(1, Input, 0, DataType::F32),   // 0..2
            rb(1, Input, 2, DataType::U16),   // 2..3
            rb(1, Input, 3, DataType::I16),   // 3..4
            rb(1, Input, 10, DataType::U16),  // gap -> own request
            rb(1, Holding, 0, DataType::U16), // other table
            rb(2, Input, 0, DataType::U16),   // other unit
        ];
        let plan = ReadPlan::new(&list).unwrap();
        let r: Vec<(u8, RegisterTable, u16, u16)> = plan
            .requests()
            .iter()
            .map(|r| (r.unit_id, r.table, r.address, r.count))
            .collect();
        assert_eq!(
            r,
            vec![
                (1, Holding, 0, 1),
                (1, Input, 0, 6),
                (1, Input, 10, 1),
                (2, Input, 0, 1)
            ]
        );
        assert_eq!(plan.members(&plan.requests()[1]), &[1, 2, 3, 0]);
    }

    #[test]
    fn read_requests_respect_the_register_limit() {
        // 70 consecutive f32 = 140 registers -> 2 requests (124 + 16: no f32 is split).
        let list: Vec<_> = (0..70)
            .map(|k| rb(1, Holding, 2 * k, DataType::F32))
            .collect();
        let plan = ReadPlan::new(&list).unwrap();
        let counts: Vec<u16> = plan.requests().iter().map(|r| r.count).collect();
        assert_eq!(counts, vec![124, 16]);
        assert!(plan
            .requests()
            .iter()
            .all(|r| r.count <= MAX_READ_REGISTERS));
    }

    #[test]
    fn overlapping_reads_merge() {
        let list = [
            rb(1, Holding, 0, DataType::F64),
            rb(1, Holding, 2, DataType::F32),
        ];
        let plan = ReadPlan::new(&list).unwrap();
        assert_eq!(plan.requests().len(), 1);
        assert_eq!(plan.requests()[0].count, 4);
    }

    #[test]
    fn write_plan_rejects_input_table_and_overlaps() {
        assert_eq!(
            WritePlan::new(&[
                rb(1, Holding, 0, DataType::U16),
                rb(1, Input, 0, DataType::U16)
            ]),
            Err(PlanError::ReadOnlyTable {
                index: 1,
                table: Input
            })
        );
        assert_eq!(
            WritePlan::new(&[
                rb(1, Holding, 0, DataType::F32),
                rb(1, Holding, 1, DataType::U16)
            ]),
            Err(PlanError::Overlap {
                first: 0,
                second: 1
            })
        );
        assert!(matches!(
            ReadPlan::new(&[rb(1, Holding, 0, DataType::U16).with_scaling(0.0, 0.0)]),
            Err(PlanError::InvalidBinding { index: 0, .. })
        ));
    }

    #[test]
    fn contiguous_coils_share_one_request_and_discrete_inputs_are_read_only() {
        use RegisterTable::{Coil, DiscreteInput};
        let coils = [
            rb(1, Coil, 2, DataType::Bool),
            rb(1, Coil, 0, DataType::Bool),
            rb(1, Coil, 1, DataType::Bool),
            rb(1, Coil, 5, DataType::Bool), // gap: own request
            rb(1, Holding, 0, DataType::U16),
        ];
        let w = WritePlan::new(&coils).unwrap();
        let r: Vec<(RegisterTable, u16, u16)> = w
            .requests()
            .iter()
            .map(|q| (q.table, q.address, q.count))
            .collect();
        assert_eq!(r, [(Holding, 0, 1), (Coil, 0, 3), (Coil, 5, 1)]);
        let read = ReadPlan::new(&[
            rb(1, DiscreteInput, 0, DataType::Bool),
            rb(1, DiscreteInput, 1, DataType::Bool),
            rb(1, Input, 1, DataType::U16),
        ])
        .unwrap();
        let r: Vec<(RegisterTable, u16, u16)> = read
            .requests()
            .iter()
            .map(|q| (q.table, q.address, q.count))
            .collect();
        assert_eq!(r, [(Input, 1, 1), (DiscreteInput, 0, 2)]);
        assert_eq!(
            WritePlan::new(&[rb(1, DiscreteInput, 0, DataType::Bool)]),
            Err(PlanError::ReadOnlyTable {
                index: 0,
                table: DiscreteInput
            })
        );
        assert!(matches!(
            WritePlan::new(&[rb(1, Coil, 0, DataType::U16)]),
            Err(PlanError::InvalidBinding { index: 0, .. })
        ));
    }

    #[test]
    fn bit_requests_respect_the_bit_limits() {
        // 2100 contiguous coils: reads of 2000 + 100 bits, writes of 1968 + 132 coils
        let list: Vec<_> = (0..2100)
            .map(|k| rb(1, RegisterTable::Coil, k, DataType::Bool))
            .collect();
        let counts = |r: &[PlannedRequest]| r.iter().map(|q| q.count).collect::<Vec<_>>();
        assert_eq!(
            counts(ReadPlan::new(&list).unwrap().requests()),
            [2000, 100]
        );
        assert_eq!(
            counts(WritePlan::new(&list).unwrap().requests()),
            [1968, 132]
        );
    }

    #[test]
    fn separate_write_plan_never_merges() {
        let list = [
            rb(1, RegisterTable::Holding, 0, DataType::U16),
            rb(1, RegisterTable::Holding, 1, DataType::F32),
            rb(1, RegisterTable::Holding, 3, DataType::U16),
        ];
        assert_eq!(WritePlan::new(&list).unwrap().requests().len(), 1);
        let sep = WritePlan::separate(&list).unwrap();
        let r: Vec<(u16, u16)> = sep
            .requests()
            .iter()
            .map(|q| (q.address, q.count))
            .collect();
        assert_eq!(r, [(0, 1), (1, 2), (3, 1)]);
    }

    #[test]
    fn write_plan_word_offsets_are_contiguous() {
        let list = [
            rb(1, Holding, 100, DataType::F32),
            rb(1, Holding, 0, DataType::U16),
            rb(1, Holding, 1, DataType::F32),
        ];
        let plan = WritePlan::new(&list).unwrap();
        let reqs = plan.requests();
        assert_eq!(reqs.len(), 2);
        assert_eq!((reqs[0].address, reqs[0].count), (0, 3));
        assert_eq!((reqs[1].address, reqs[1].count), (100, 2));
        assert_eq!(WritePlan::word_offset(&reqs[0]), 0);
        assert_eq!(WritePlan::word_offset(&reqs[1]), 3);
        assert_eq!(plan.total_words(), 5);
    }
}
