//! Modbus server over a shared register image, for the simulated plant and HIL tests.
//!
//! The owner (the simulated plant) keeps a [`SharedImage`]: it writes sensor values into
//! input/holding registers with [`RegisterImage::set_value`] and reads back the actuator
//! setpoints clients wrote into holding registers with [`RegisterImage::value`]. Only
//! registers that were mapped exist; requests touching anything else get an
//! "illegal data address" exception, like a real device.
//!
//! For fault injection the image carries a [`ResponseMode`]: a server can be made to stop
//! answering or to answer late, without closing connections.

use std::collections::BTreeMap;
use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use thiserror::Error;
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;
use tokio_modbus::server::Service;
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

use super::client::RtuConfig;
use super::plan::{MAX_READ_REGISTERS, MAX_WRITE_REGISTERS};
use super::register::{EncodeError, EncodeOutcome, RegisterBinding, RegisterTable};

/// How the server treats incoming requests; for fault injection in tests.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ResponseMode {
    /// Process and answer at once.
    #[default]
    Normal,
    /// Read and discard requests: no processing, no answer (a hung device).
    Silent,
    /// Process at once, answer after the delay (a slow device; the late answer of
    /// tokio-modbus issue 324).
    Delay(Duration),
}

/// Registers of one unit id. Coils and discrete inputs are stored as words 0/1.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct UnitRegisters {
    holding: BTreeMap<u16, u16>,
    input: BTreeMap<u16, u16>,
    coil: BTreeMap<u16, u16>,
    discrete_input: BTreeMap<u16, u16>,
}

impl UnitRegisters {
    fn table(&self, table: RegisterTable) -> &BTreeMap<u16, u16> {
        match table {
            RegisterTable::Holding => &self.holding,
            RegisterTable::Input => &self.input,
            RegisterTable::Coil => &self.coil,
            RegisterTable::DiscreteInput => &self.discrete_input,
        }
    }
    fn table_mut(&mut self, table: RegisterTable) -> &mut BTreeMap<u16, u16> {
        match table {
            RegisterTable::Holding => &mut self.holding,
            RegisterTable::Input => &mut self.input,
            RegisterTable::Coil => &mut self.coil,
            RegisterTable::DiscreteInput => &mut self.discrete_input,
        }
    }
}

/// Serve the bit-table requests (read coils / discrete inputs, write coils) from `image`.
/// `None`: not a bit request. `Some(Ok(n))`: answered; `n` coils were written (0 for reads).
pub(crate) fn handle_bits(
    image: &mut RegisterImage,
    unit_id: u8,
    request: &Request<'_>,
) -> Option<Result<(Response, u16), ExceptionCode>> {
    use super::plan::{MAX_READ_BITS, MAX_WRITE_BITS};
    let addr_err = |_| ExceptionCode::IllegalDataAddress;
    Some(match request {
        Request::ReadCoils(addr, cnt) | Request::ReadDiscreteInputs(addr, cnt) => {
            let coils = matches!(request, Request::ReadCoils(..));
            let table = if coils {
                RegisterTable::Coil
            } else {
                RegisterTable::DiscreteInput
            };
            if *cnt == 0 || *cnt > MAX_READ_BITS {
                return Some(Err(ExceptionCode::IllegalDataValue));
            }
            let mut words = vec![0u16; usize::from(*cnt)];
            image
                .read_words(unit_id, table, *addr, &mut words)
                .map_err(addr_err)
                .map(|()| {
                    let bits: Vec<bool> = words.iter().map(|&w| w != 0).collect();
                    let response = if coils {
                        Response::ReadCoils(bits)
                    } else {
                        Response::ReadDiscreteInputs(bits)
                    };
                    (response, 0)
                })
        }
        Request::WriteSingleCoil(addr, on) => image
            .write_words(unit_id, RegisterTable::Coil, *addr, &[u16::from(*on)])
            .map_err(addr_err)
            .map(|()| (Response::WriteSingleCoil(*addr, *on), 1)),
        Request::WriteMultipleCoils(addr, bits) => {
            if bits.is_empty() || bits.len() > usize::from(MAX_WRITE_BITS) {
                return Some(Err(ExceptionCode::IllegalDataValue));
            }
            let words: Vec<u16> = bits.iter().map(|&b| u16::from(b)).collect();
            let n = words.len() as u16;
            image
                .write_words(unit_id, RegisterTable::Coil, *addr, &words)
                .map_err(addr_err)
                .map(|()| (Response::WriteMultipleCoils(*addr, n), n))
        }
        _ => return None,
    })
}

/// An image access that does not fit the mapped registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum ImageError {
    /// The register (or one of a range) is not mapped.
    #[error("unit {unit_id} {} register {address} is not mapped", table.name())]
    Unmapped {
        /// Unit id.
        unit_id: u8,
        /// Table.
        table: RegisterTable,
        /// First unmapped address.
        address: u16,
    },
    /// The range runs past address 65535.
    #[error("register range runs past address 65535")]
    AddressOverflow,
    /// The value could not be encoded (NaN).
    #[error("cannot encode: {0}")]
    Encode(#[from] EncodeError),
}

/// Holding and input registers per unit id, plus fault-injection settings.
#[derive(Debug, Clone, Default)]
pub struct RegisterImage {
    units: BTreeMap<u8, UnitRegisters>,
    mode: ResponseMode,
    client_writes: u64,
}

/// The image as shared between its owner and the server tasks.
pub type SharedImage = Arc<Mutex<RegisterImage>>;

/// Lock a shared image. A poisoned lock (an owner panicked while holding it) is recovered:
/// registers are plain integers, so there is no invariant a panic could have broken.
pub fn lock_image(image: &SharedImage) -> MutexGuard<'_, RegisterImage> {
    image
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl RegisterImage {
    /// An empty image (no unit, no register).
    pub fn new() -> RegisterImage {
        RegisterImage::default()
    }

    /// Wrap in `Arc<Mutex<_>>` for sharing with a server.
    pub fn into_shared(self) -> SharedImage {
        Arc::new(Mutex::new(self))
    }

    /// Map `count` registers from `address` (initialised to 0; already mapped registers keep
    /// their value). Addresses past 65535 are ignored.
    pub fn map(&mut self, unit_id: u8, table: RegisterTable, address: u16, count: u16) {
        let regs = self.units.entry(unit_id).or_default().table_mut(table);
        for a in
            (u32::from(address)..u32::from(address) + u32::from(count)).take_while(|&a| a <= 0xFFFF)
        {
            regs.entry(a as u16).or_insert(0);
        }
    }

    /// Map the registers a binding spans.
    pub fn map_binding(&mut self, binding: &RegisterBinding) {
        self.map(
            binding.unit_id,
            binding.table,
            binding.address,
            binding.register_count(),
        );
    }

    /// Whether a unit id has any register.
    pub fn has_unit(&self, unit_id: u8) -> bool {
        self.units.contains_key(&unit_id)
    }

    fn check(
        &self,
        unit_id: u8,
        table: RegisterTable,
        address: u16,
        count: usize,
    ) -> Result<(), ImageError> {
        if u32::from(address) + count as u32 > 1 << 16 {
            return Err(ImageError::AddressOverflow);
        }
        let regs = self.units.get(&unit_id).map(|u| u.table(table));
        for k in 0..count {
            let a = address + k as u16;
            if !regs.is_some_and(|r| r.contains_key(&a)) {
                return Err(ImageError::Unmapped {
                    unit_id,
                    table,
                    address: a,
                });
            }
        }
        Ok(())
    }

    /// Copy `out.len()` registers starting at `address` into `out`. All must be mapped.
    pub fn read_words(
        &self,
        unit_id: u8,
        table: RegisterTable,
        address: u16,
        out: &mut [u16],
    ) -> Result<(), ImageError> {
        self.check(unit_id, table, address, out.len())?;
        if let Some(regs) = self.units.get(&unit_id).map(|u| u.table(table)) {
            for (k, w) in out.iter_mut().enumerate() {
                *w = regs.get(&(address + k as u16)).copied().unwrap_or(0);
            }
        }
        Ok(())
    }

    /// Store `words` starting at `address`. All must be mapped; on error nothing changes.
    pub fn write_words(
        &mut self,
        unit_id: u8,
        table: RegisterTable,
        address: u16,
        words: &[u16],
    ) -> Result<(), ImageError> {
        self.check(unit_id, table, address, words.len())?;
        if let Some(unit) = self.units.get_mut(&unit_id) {
            let regs = unit.table_mut(table);
            for (k, &w) in words.iter().enumerate() {
                regs.insert(address + k as u16, w);
            }
        }
        Ok(())
    }

    /// Encode an SI value through `binding` into its (mapped) registers.
    pub fn set_value(
        &mut self,
        binding: &RegisterBinding,
        value: f64,
    ) -> Result<EncodeOutcome, ImageError> {
        let mut words = [0u16; 4];
        let outcome = binding.encode(value, &mut words)?;
        let n = binding.register_count() as usize;
        self.write_words(binding.unit_id, binding.table, binding.address, &words[..n])?;
        Ok(outcome)
    }

    /// Decode the SI value a binding's registers hold.
    pub fn value(&self, binding: &RegisterBinding) -> Result<f64, ImageError> {
        let mut words = [0u16; 4];
        let n = binding.register_count() as usize;
        self.read_words(
            binding.unit_id,
            binding.table,
            binding.address,
            &mut words[..n],
        )?;
        // `words` holds 4 registers, enough for every data type.
        Ok(binding.decode(&words).unwrap_or(f64::NAN))
    }

    /// Current response mode.
    pub fn response_mode(&self) -> ResponseMode {
        self.mode
    }

    /// Change how requests are answered (takes effect for the next request).
    pub fn set_response_mode(&mut self, mode: ResponseMode) {
        self.mode = mode;
    }

    /// Number of successful write requests served (lets the owner see that a client is
    /// alive and commanding).
    pub fn client_writes(&self) -> u64 {
        self.client_writes
    }

    /// Serve one request. `None`: stay silent (RTU request for a unit that is not here).
    fn handle(
        &mut self,
        unit_id: u8,
        request: &Request<'_>,
        rtu: bool,
    ) -> Result<Option<Response>, ExceptionCode> {
        if !self.has_unit(unit_id) {
            // On a serial bus another device may own the id; through TCP we act as a
            // gateway whose target does not answer.
            return if rtu {
                Ok(None)
            } else {
                Err(ExceptionCode::GatewayTargetDevice)
            };
        }
        let addr_err = |_| ExceptionCode::IllegalDataAddress;
        match request {
            Request::ReadHoldingRegisters(addr, cnt) | Request::ReadInputRegisters(addr, cnt) => {
                let table = if matches!(request, Request::ReadHoldingRegisters(..)) {
                    RegisterTable::Holding
                } else {
                    RegisterTable::Input
                };
                if *cnt == 0 || *cnt > MAX_READ_REGISTERS {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                let mut words = vec![0u16; *cnt as usize];
                self.read_words(unit_id, table, *addr, &mut words)
                    .map_err(addr_err)?;
                Ok(Some(if table == RegisterTable::Holding {
                    Response::ReadHoldingRegisters(words)
                } else {
                    Response::ReadInputRegisters(words)
                }))
            }
            Request::WriteSingleRegister(addr, word) => {
                self.write_words(unit_id, RegisterTable::Holding, *addr, &[*word])
                    .map_err(addr_err)?;
                self.client_writes += 1;
                Ok(Some(Response::WriteSingleRegister(*addr, *word)))
            }
            Request::WriteMultipleRegisters(addr, words) => {
                if words.is_empty() || words.len() > MAX_WRITE_REGISTERS as usize {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                self.write_words(unit_id, RegisterTable::Holding, *addr, words)
                    .map_err(addr_err)?;
                self.client_writes += 1;
                Ok(Some(Response::WriteMultipleRegisters(
                    *addr,
                    words.len() as u16,
                )))
            }
            Request::MaskWriteRegister(addr, and_mask, or_mask) => {
                let mut w = [0u16];
                self.read_words(unit_id, RegisterTable::Holding, *addr, &mut w)
                    .map_err(addr_err)?;
                w[0] = (w[0] & and_mask) | (or_mask & !and_mask);
                self.write_words(unit_id, RegisterTable::Holding, *addr, &w)
                    .map_err(addr_err)?;
                self.client_writes += 1;
                Ok(Some(Response::MaskWriteRegister(
                    *addr, *and_mask, *or_mask,
                )))
            }
            Request::ReadWriteMultipleRegisters(read_addr, read_cnt, write_addr, words) => {
                // Spec limits for function 0x17: read 1..=125, write 1..=121 registers.
                if *read_cnt == 0 || *read_cnt > 125 || words.is_empty() || words.len() > 121 {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                // Check the read range first so that a bad read leaves the image untouched.
                self.check(
                    unit_id,
                    RegisterTable::Holding,
                    *read_addr,
                    *read_cnt as usize,
                )
                .map_err(addr_err)?;
                self.write_words(unit_id, RegisterTable::Holding, *write_addr, words)
                    .map_err(addr_err)?;
                self.client_writes += 1;
                let mut out = vec![0u16; *read_cnt as usize];
                self.read_words(unit_id, RegisterTable::Holding, *read_addr, &mut out)
                    .map_err(addr_err)?;
                Ok(Some(Response::ReadWriteMultipleRegisters(out)))
            }
            _ => match handle_bits(self, unit_id, request) {
                Some(r) => {
                    let (response, written) = r?;
                    if written > 0 {
                        self.client_writes += 1;
                    }
                    Ok(Some(response))
                }
                None => Err(ExceptionCode::IllegalFunction),
            },
        }
    }
}

type ServiceFuture = Pin<Box<dyn Future<Output = Result<Option<Response>, ExceptionCode>> + Send>>;

/// tokio-modbus service answering from a shared image.
#[derive(Debug, Clone)]
struct ImageService {
    image: SharedImage,
    rtu: bool,
}

impl Service for ImageService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = ServiceFuture;

    fn call(&self, req: Self::Request) -> Self::Future {
        let (mode, result) = {
            let mut image = lock_image(&self.image);
            let mode = image.mode;
            if mode == ResponseMode::Silent {
                (mode, Ok(None))
            } else if req.slave == 0 && self.rtu {
                // RTU broadcast: never answered. Not supported as a write to all units.
                (mode, Ok(None))
            } else {
                (mode, image.handle(req.slave, &req.request, self.rtu))
            }
        };
        match mode {
            ResponseMode::Delay(d) => Box::pin(async move {
                tokio::time::sleep(d).await;
                result
            }),
            _ => Box::pin(std::future::ready(result)),
        }
    }
}

/// A running Modbus TCP server. Dropping it (or [`shutdown`](Self::shutdown)) stops the
/// listener and closes every client connection.
#[derive(Debug)]
pub struct TcpServerHandle {
    local_addr: SocketAddr,
    task: Option<JoinHandle<()>>,
}

impl TcpServerHandle {
    /// A handle on a server task listening on `local_addr`.
    pub(crate) fn from_task(local_addr: SocketAddr, task: JoinHandle<()>) -> TcpServerHandle {
        TcpServerHandle {
            local_addr,
            task: Some(task),
        }
    }

    /// The address the server listens on (useful after binding port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// Stop the server and close its connections; returns once the listener is closed.
    pub async fn shutdown(mut self) {
        if let Some(task) = self.task.take() {
            task.abort();
            let _ = task.await;
        }
    }
}

impl Drop for TcpServerHandle {
    fn drop(&mut self) {
        if let Some(task) = &self.task {
            task.abort();
        }
    }
}

/// Serve `image` over Modbus TCP on `addr` (use port 0 for a free port).
pub async fn spawn_tcp_server(addr: SocketAddr, image: SharedImage) -> io::Result<TcpServerHandle> {
    let listener = TcpListener::bind(addr).await?;
    spawn_tcp_server_on(listener, image)
}

/// Serve `image` over Modbus TCP on an already bound listener.
pub fn spawn_tcp_server_on(
    listener: TcpListener,
    image: SharedImage,
) -> io::Result<TcpServerHandle> {
    let local_addr = listener.local_addr()?;
    let service = ImageService { image, rtu: false };
    let server = tokio_modbus::server::tcp::Server::new(listener);
    let task = tokio::spawn(async move {
        let on_connected = move |stream: TcpStream, peer: SocketAddr| {
            let service = service.clone();
            async move {
                let _ = stream.set_nodelay(true);
                tracing::debug!(target: "modbus", %peer, "client connected");
                // malformed requests never reach tokio-modbus's decoder (issue 12, item 9)
                Ok(Some((
                    service,
                    super::request_guard::guard_connection(stream, peer),
                )))
            }
        };
        let on_error =
            |e: io::Error| tracing::debug!(target: "modbus", error = %e, "connection ended");
        if let Err(e) = server.serve(&on_connected, on_error).await {
            tracing::warn!(target: "modbus", error = %e, "Modbus TCP server stopped");
        }
    });
    Ok(TcpServerHandle {
        local_addr,
        task: Some(task),
    })
}

/// A running Modbus RTU server on a serial port. Dropping it stops the server.
#[derive(Debug)]
pub struct RtuServerHandle {
    task: JoinHandle<()>,
}

impl RtuServerHandle {
    /// Stop the server and release the serial port.
    pub fn shutdown(self) {
        self.task.abort();
    }
}

impl Drop for RtuServerHandle {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Serve `image` over Modbus RTU on an open serial stream (e.g. one end of
/// `tokio_serial::SerialStream::pair()`). Requests for unit ids without registers, and
/// broadcasts (unit 0), are not answered.
pub fn spawn_rtu_server(serial: tokio_serial::SerialStream, image: SharedImage) -> RtuServerHandle {
    let service = ImageService { image, rtu: true };
    let server = tokio_modbus::server::rtu::Server::new(serial);
    let task = tokio::spawn(async move {
        if let Err(e) = server.serve_forever(service).await {
            tracing::warn!(target: "modbus", error = %e, "Modbus RTU server stopped");
        }
    });
    RtuServerHandle { task }
}

/// Open the serial port described by `config` and serve `image` on it.
pub fn open_rtu_server(config: &RtuConfig, image: SharedImage) -> io::Result<RtuServerHandle> {
    let serial = tokio_serial::SerialStream::open(&config.builder())?;
    Ok(spawn_rtu_server(serial, image))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::modbus::register::DataType;
    use std::borrow::Cow;

    fn image() -> RegisterImage {
        let mut img = RegisterImage::new();
        img.map(1, RegisterTable::Holding, 10, 4); // 10..14
        img.map(1, RegisterTable::Input, 0, 2);
        img
    }

    #[test]
    fn unmapped_access_is_refused_and_changes_nothing() {
        let mut img = image();
        assert_eq!(
            img.write_words(1, RegisterTable::Holding, 12, &[1, 2, 3]),
            Err(ImageError::Unmapped {
                unit_id: 1,
                table: RegisterTable::Holding,
                address: 14
            })
        );
        let mut out = [9u16; 4];
        img.read_words(1, RegisterTable::Holding, 10, &mut out)
            .unwrap();
        assert_eq!(out, [0; 4], "failed write must not be partially applied");
        assert!(img
            .read_words(2, RegisterTable::Holding, 10, &mut out)
            .is_err());
        assert_eq!(
            img.read_words(1, RegisterTable::Input, 65535, &mut out),
            Err(ImageError::AddressOverflow)
        );
    }

    #[test]
    fn values_through_bindings() {
        let mut img = image();
        let b = RegisterBinding::new(1, RegisterTable::Holding, 10, DataType::F32);
        assert_eq!(img.set_value(&b, 2.5), Ok(EncodeOutcome::InRange));
        assert_eq!(img.value(&b), Ok(2.5));
        assert_eq!(
            img.set_value(&b, f64::NAN),
            Err(ImageError::Encode(EncodeError::NotANumber))
        );
        let unmapped = RegisterBinding::new(1, RegisterTable::Holding, 13, DataType::F32);
        assert!(matches!(
            img.set_value(&unmapped, 1.0),
            Err(ImageError::Unmapped { address: 14, .. })
        ));
    }

    #[test]
    fn request_handling() {
        let mut img = image();
        let h = |img: &mut RegisterImage, unit: u8, r: Request<'_>, rtu: bool| {
            img.handle(unit, &r, rtu)
        };
        assert_eq!(
            h(&mut img, 1, Request::WriteSingleRegister(11, 0x00F0), false),
            Ok(Some(Response::WriteSingleRegister(11, 0x00F0)))
        );
        assert_eq!(
            h(
                &mut img,
                1,
                Request::MaskWriteRegister(11, 0xFF0F, 0x0050),
                false
            ),
            Ok(Some(Response::MaskWriteRegister(11, 0xFF0F, 0x0050)))
        );
        // Bits 4..7 come from the OR mask, the rest from the old value: 0x00F0 -> 0x0050.
        let mut w = [0u16];
        img.read_words(1, RegisterTable::Holding, 11, &mut w)
            .unwrap();
        assert_eq!(w[0], 0x0050);
        assert_eq!(
            h(
                &mut img,
                1,
                Request::ReadWriteMultipleRegisters(10, 2, 12, Cow::Borrowed(&[7, 8])),
                false
            ),
            Ok(Some(Response::ReadWriteMultipleRegisters(vec![0, 0x0050])))
        );
        assert_eq!(
            h(&mut img, 1, Request::ReadHoldingRegisters(12, 2), false),
            Ok(Some(Response::ReadHoldingRegisters(vec![7, 8])))
        );
        assert_eq!(
            h(&mut img, 1, Request::ReadHoldingRegisters(10, 0), false),
            Err(ExceptionCode::IllegalDataValue)
        );
        assert_eq!(
            h(&mut img, 1, Request::ReadHoldingRegisters(10, 126), false),
            Err(ExceptionCode::IllegalDataValue)
        );
        assert_eq!(
            h(&mut img, 1, Request::ReadInputRegisters(1, 2), false),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            h(&mut img, 1, Request::ReadCoils(0, 1), false),
            Err(ExceptionCode::IllegalDataAddress),
            "no coil mapped"
        );
        // Unknown unit: gateway exception over TCP, silence on a serial bus.
        assert_eq!(
            h(&mut img, 5, Request::ReadInputRegisters(0, 1), false),
            Err(ExceptionCode::GatewayTargetDevice)
        );
        assert_eq!(
            h(&mut img, 5, Request::ReadInputRegisters(0, 1), true),
            Ok(None)
        );
        assert_eq!(img.client_writes(), 3);
    }

    #[test]
    fn coils_and_discrete_inputs_are_served() {
        let mut img = image();
        img.map(1, RegisterTable::Coil, 0, 3);
        img.map(1, RegisterTable::DiscreteInput, 4, 2);
        let di = RegisterBinding::new(1, RegisterTable::DiscreteInput, 5, DataType::Bool);
        assert_eq!(img.set_value(&di, 1.0), Ok(EncodeOutcome::InRange));
        let mut h = |r: Request<'_>| img.handle(1, &r, false);
        assert_eq!(
            h(Request::WriteMultipleCoils(
                0,
                Cow::Borrowed(&[true, false, true])
            )),
            Ok(Some(Response::WriteMultipleCoils(0, 3)))
        );
        assert_eq!(
            h(Request::WriteSingleCoil(1, true)),
            Ok(Some(Response::WriteSingleCoil(1, true)))
        );
        assert_eq!(
            h(Request::ReadCoils(0, 3)),
            Ok(Some(Response::ReadCoils(vec![true, true, true])))
        );
        assert_eq!(
            h(Request::ReadDiscreteInputs(4, 2)),
            Ok(Some(Response::ReadDiscreteInputs(vec![false, true])))
        );
        // a coil the device does not have: exception 2, nothing written
        assert_eq!(
            h(Request::WriteMultipleCoils(
                2,
                Cow::Borrowed(&[false, false])
            )),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            h(Request::ReadCoils(0, 2001)),
            Err(ExceptionCode::IllegalDataValue)
        );
        // discrete inputs cannot be written (there is no function for it)
        assert_eq!(
            h(Request::ReadDiscreteInputs(3, 1)),
            Err(ExceptionCode::IllegalDataAddress)
        );
        let c = RegisterBinding::new(1, RegisterTable::Coil, 2, DataType::Bool);
        assert_eq!(img.value(&c), Ok(1.0));
        assert_eq!(img.client_writes(), 2);
    }
}
