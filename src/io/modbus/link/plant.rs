//! The plant node's Modbus TCP server: sensors from the snapshot board, setpoint writes into
//! the command board, write arrivals into the heartbeat board.
//!
//! The server answers from a [`RegisterImage`] mapped from the signal map (so only mapped
//! registers exist, like a real device). Instead of a refresh loop, each read request first
//! re-encodes the sensor registers if the [`SnapshotBoard`] holds a newer snapshot than the
//! image: an answer always carries the latest published snapshot, at no cost while nobody
//! reads. Writes are published with the monotonic time the request reached the service.
//!
//! The boards are single-writer seqlocks; connection tasks call the service concurrently, but
//! every publish happens while the image mutex is held, so the writes to each board are
//! serialised.

use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use tokio::net::{TcpListener, TcpSocket, TcpStream};
use tokio_modbus::server::Service;
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

use super::{
    check_map, counters, HeartbeatRegister, HeartbeatWords, LinkError, ModbusServerConfig,
    HEARTBEAT_REGISTERS,
};
use crate::io::modbus::plan::{max_count, MAX_WRITE_REGISTERS};
use crate::io::modbus::register::{RegisterBinding, RegisterTable};
use crate::io::modbus::server::{
    handle_bits, lock_image, RegisterImage, ResponseMode, SharedImage,
};
use crate::io::signal_map::SignalMap;
use crate::runtime::handoff::{
    monotonic_ns, CommandBoard, HeartbeatBoard, HeartbeatSeen, SnapshotBoard,
};
use crate::vocab::signals::{ActuatorId, SensorId};
use crate::vocab::Mode;

/// Mode reported for a heartbeat inferred from a plain client write (no heartbeat block), or
/// read as an unknown code: auto.
const INFERRED_MODE: Mode = Mode::Auto;

counters! {
    /// Plant server counters (atomics, updated by the connection tasks).
    atomic PlantCounters;
    /// A copy of [`PlantCounters`].
    plain PlantCounts;
    {
        /// Client connections accepted.
        connections,
        /// Requests received (answered or not).
        requests,
        /// Read requests answered.
        reads,
        /// Write requests applied.
        writes,
        /// Exception answers sent.
        exceptions,
        /// Requests left unanswered (fault injection: [`ResponseMode::Silent`]).
        dropped,
        /// Times the sensor registers were re-encoded from a new snapshot.
        refreshes,
        /// Setpoints published into the command board.
        commands,
        /// Heartbeats published into the heartbeat board.
        heartbeats,
        /// Writes refused because the client is not in `allow_writes_from`.
        refused_writes,
    }
}

/// Per-server mutable state, locked after the image.
#[derive(Debug)]
struct PlantState {
    /// (cycle, t_ns) of the snapshot the image holds; `None` before the first.
    snapshot: Option<(u64, u64)>,
    /// Per sensor binding: whether the image holds a value from the snapshot (false for
    /// NaN, i.e. a sensor this plant does not produce).
    sensor_valid: Vec<bool>,
    /// Client writes applied, for the inferred heartbeat's alive counter.
    writes: u64,
    /// Last value of the watched watchdog register (alive counter or toggle).
    watched: Option<f64>,
}

#[derive(Debug)]
struct Shared {
    image: SharedImage,
    state: Mutex<PlantState>,
    sensors: Vec<(SensorId, RegisterBinding)>,
    actuators: Vec<(ActuatorId, RegisterBinding)>,
    heartbeat_register: Option<HeartbeatRegister>,
    /// The map's watchdog contract: the device watchdog watches `alive` (else `toggle`).
    watchdog: Option<crate::io::modbus::watchdog::ModbusWatchdog>,
    snapshots: Arc<SnapshotBoard>,
    commands: Arc<CommandBoard>,
    heartbeat: Arc<HeartbeatBoard>,
    counters: Arc<PlantCounters>,
}

fn binding_in(b: &RegisterBinding, unit_id: u8, table: RegisterTable, addr: u16, n: u16) -> bool {
    b.unit_id == unit_id
        && b.table == table
        && u32::from(b.address) < u32::from(addr) + u32::from(n)
        && u32::from(addr) < b.end_address()
}

impl Shared {
    fn lock_state(&self) -> MutexGuard<'_, PlantState> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Re-encode the sensor registers if a newer snapshot was published.
    fn refresh(&self, image: &mut RegisterImage, state: &mut PlantState) {
        let Some((snap, cycle, t_ns)) = self.snapshots.latest() else {
            return;
        };
        if state.snapshot == Some((cycle, t_ns)) {
            return;
        }
        state.snapshot = Some((cycle, t_ns));
        for ((id, b), valid) in self.sensors.iter().zip(state.sensor_valid.iter_mut()) {
            *valid = image.set_value(b, snap.get(*id)).is_ok();
        }
        self.counters.refreshes.fetch_add(1, Ordering::Relaxed);
    }

    /// Handle one request; `None` = no answer.
    fn handle(
        &self,
        unit_id: u8,
        request: &Request<'_>,
        t_ns: u64,
    ) -> (ResponseMode, Result<Option<Response>, ExceptionCode>) {
        let c = &self.counters;
        c.requests.fetch_add(1, Ordering::Relaxed);
        let mut image = lock_image(&self.image);
        let mode = image.response_mode();
        if mode == ResponseMode::Silent {
            c.dropped.fetch_add(1, Ordering::Relaxed);
            return (mode, Ok(None));
        }
        let mut state = self.lock_state();
        let result = self.dispatch(&mut image, &mut state, unit_id, request, t_ns);
        if result.is_err() {
            c.exceptions.fetch_add(1, Ordering::Relaxed);
        }
        (mode, result.map(Some))
    }

    fn dispatch(
        &self,
        image: &mut RegisterImage,
        state: &mut PlantState,
        unit_id: u8,
        request: &Request<'_>,
        t_ns: u64,
    ) -> Result<Response, ExceptionCode> {
        if !image.has_unit(unit_id) {
            // TCP: we act as a gateway whose target device does not answer.
            return Err(ExceptionCode::GatewayTargetDevice);
        }
        let unmapped = |_| ExceptionCode::IllegalDataAddress;
        match request {
            Request::ReadHoldingRegisters(addr, cnt)
            | Request::ReadInputRegisters(addr, cnt)
            | Request::ReadCoils(addr, cnt)
            | Request::ReadDiscreteInputs(addr, cnt) => {
                let table = match request {
                    Request::ReadHoldingRegisters(..) => RegisterTable::Holding,
                    Request::ReadInputRegisters(..) => RegisterTable::Input,
                    Request::ReadCoils(..) => RegisterTable::Coil,
                    _ => RegisterTable::DiscreteInput,
                };
                if *cnt == 0 || *cnt > max_count(table, true) {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                self.refresh(image, state);
                let mut words = vec![0u16; usize::from(*cnt)];
                image
                    .read_words(unit_id, table, *addr, &mut words)
                    .map_err(unmapped)?;
                let stale = self
                    .sensors
                    .iter()
                    .zip(&state.sensor_valid)
                    .any(|((_, b), ok)| !ok && binding_in(b, unit_id, table, *addr, *cnt));
                if stale {
                    // No snapshot yet: busy (transient). A NaN sensor: the device has no
                    // value to give for it.
                    return Err(if state.snapshot.is_none() {
                        ExceptionCode::ServerDeviceBusy
                    } else {
                        ExceptionCode::ServerDeviceFailure
                    });
                }
                self.counters.reads.fetch_add(1, Ordering::Relaxed);
                let bits = || words.iter().map(|&w| w != 0).collect();
                Ok(match table {
                    RegisterTable::Holding => Response::ReadHoldingRegisters(words),
                    RegisterTable::Input => Response::ReadInputRegisters(words),
                    RegisterTable::Coil => Response::ReadCoils(bits()),
                    RegisterTable::DiscreteInput => Response::ReadDiscreteInputs(bits()),
                })
            }
            Request::WriteSingleCoil(..) | Request::WriteMultipleCoils(..) => {
                match handle_bits(image, unit_id, request) {
                    Some(Ok((response, n))) => {
                        let addr = match request {
                            Request::WriteSingleCoil(a, _) | Request::WriteMultipleCoils(a, _) => {
                                *a
                            }
                            _ => 0,
                        };
                        self.after_write(image, state, unit_id, RegisterTable::Coil, addr, n, t_ns);
                        Ok(response)
                    }
                    Some(Err(e)) => Err(e),
                    None => Err(ExceptionCode::IllegalFunction),
                }
            }
            Request::WriteSingleRegister(addr, word) => {
                image
                    .write_words(unit_id, RegisterTable::Holding, *addr, &[*word])
                    .map_err(unmapped)?;
                self.after_write(
                    image,
                    state,
                    unit_id,
                    RegisterTable::Holding,
                    *addr,
                    1,
                    t_ns,
                );
                Ok(Response::WriteSingleRegister(*addr, *word))
            }
            Request::WriteMultipleRegisters(addr, words) => {
                if words.is_empty() || words.len() > usize::from(MAX_WRITE_REGISTERS) {
                    return Err(ExceptionCode::IllegalDataValue);
                }
                image
                    .write_words(unit_id, RegisterTable::Holding, *addr, words)
                    .map_err(unmapped)?;
                let n = words.len() as u16;
                self.after_write(
                    image,
                    state,
                    unit_id,
                    RegisterTable::Holding,
                    *addr,
                    n,
                    t_ns,
                );
                Ok(Response::WriteMultipleRegisters(*addr, n))
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }

    /// Publish the setpoints a write (of `table`: holding registers or coils) touched, and
    /// the heartbeat.
    #[allow(clippy::too_many_arguments)]
    fn after_write(
        &self,
        image: &RegisterImage,
        state: &mut PlantState,
        unit_id: u8,
        table: RegisterTable,
        addr: u16,
        n: u16,
        t_ns: u64,
    ) {
        let c = &self.counters;
        c.writes.fetch_add(1, Ordering::Relaxed);
        state.writes = state.writes.wrapping_add(1);
        for (id, b) in &self.actuators {
            if binding_in(b, unit_id, table, addr, n) {
                if let Ok(v) = image.value(b) {
                    self.commands.publish(*id, v, t_ns);
                    c.commands.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        let seen = match &self.heartbeat_register {
            Some(hb) => {
                if table != RegisterTable::Holding || !hb.touched_by(unit_id, addr, n) {
                    return;
                }
                let mut words = [0u16; HEARTBEAT_REGISTERS as usize];
                if image
                    .read_words(hb.unit_id, RegisterTable::Holding, hb.address, &mut words)
                    .is_err()
                {
                    return;
                }
                let w = HeartbeatWords::decode(&words);
                HeartbeatSeen {
                    mode: Mode::from_code(w.mode).unwrap_or(INFERRED_MODE),
                    law: w.law,
                    alive: w.alive,
                    faults: w.faults,
                    t_ns,
                }
            }
            None if self.watchdog.is_some() => {
                let Some(seen) = self.watchdog_seen(image, state, unit_id, table, addr, n, t_ns)
                else {
                    return;
                };
                seen
            }
            None => HeartbeatSeen {
                mode: INFERRED_MODE,
                law: 0,
                alive: state.writes as u8,
                faults: 0,
                t_ns,
            },
        };
        self.heartbeat.publish(&seen);
        c.heartbeats.fetch_add(1, Ordering::Relaxed);
    }
}

impl Shared {
    /// The device watchdog: a write that *changes* the watched register (alive counter or
    /// toggle) is a sign of life; a write of the same value, or of other registers, is not.
    #[allow(clippy::too_many_arguments)]
    fn watchdog_seen(
        &self,
        image: &RegisterImage,
        state: &mut PlantState,
        unit_id: u8,
        table: RegisterTable,
        addr: u16,
        n: u16,
        t_ns: u64,
    ) -> Option<HeartbeatSeen> {
        let wd = self.watchdog.as_ref()?;
        let watched = wd.alive.or(wd.toggle)?;
        if !binding_in(&watched, unit_id, table, addr, n) {
            return None;
        }
        let v = image.value(&watched).ok()?;
        if state.watched == Some(v) {
            return None;
        }
        state.watched = Some(v);
        let read = |b: Option<RegisterBinding>, default: f64| {
            b.and_then(|b| image.value(&b).ok())
                .filter(|v| v.is_finite())
                .unwrap_or(default)
        };
        Some(HeartbeatSeen {
            mode: Mode::from_code(read(wd.mode, f64::from(INFERRED_MODE.code())) as u8)
                .unwrap_or(INFERRED_MODE),
            law: read(wd.law, 0.0) as u8,
            alive: v as u64 as u8,
            faults: read(wd.faults, 0.0) as u32,
            t_ns,
        })
    }
}

type ServiceFuture = Pin<Box<dyn Future<Output = Result<Option<Response>, ExceptionCode>> + Send>>;

/// tokio-modbus service of the plant server, one per connection: `may_write` says whether
/// the peer is in `allow_writes_from`.
#[derive(Debug, Clone)]
struct PlantService {
    shared: Arc<Shared>,
    may_write: bool,
    peer: SocketAddr,
}

/// Whether `request` writes (any function that changes registers or coils).
fn is_write(request: &Request<'_>) -> bool {
    matches!(
        request,
        Request::WriteSingleRegister(..)
            | Request::WriteMultipleRegisters(..)
            | Request::WriteSingleCoil(..)
            | Request::WriteMultipleCoils(..)
            | Request::MaskWriteRegister(..)
            | Request::ReadWriteMultipleRegisters(..)
    )
}

/// Log a refused write at most once per [`REFUSED_LOG_EVERY_S`], with the count since.
fn log_refused_write(peer: SocketAddr) {
    static LAST_S: AtomicU64 = AtomicU64::new(0);
    static SUPPRESSED: AtomicU64 = AtomicU64::new(0);
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let last = LAST_S.load(Ordering::Relaxed);
    if (last == 0 || now >= last + REFUSED_LOG_EVERY_S)
        && LAST_S
            .compare_exchange(last, now, Ordering::Relaxed, Ordering::Relaxed)
            .is_ok()
    {
        let more = SUPPRESSED.swap(0, Ordering::Relaxed);
        tracing::warn!(target: "modbus", %peer, "plant server: write refused, client not in allow_writes_from ({more} more refused since the last message)");
    } else {
        SUPPRESSED.fetch_add(1, Ordering::Relaxed);
    }
}

/// Refused writes are logged at most this often, seconds.
const REFUSED_LOG_EVERY_S: u64 = 10;

impl Service for PlantService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = ServiceFuture;

    fn call(&self, req: Self::Request) -> Self::Future {
        if !self.may_write && is_write(&req.request) {
            let c = &self.shared.counters;
            c.requests.fetch_add(1, Ordering::Relaxed);
            c.refused_writes.fetch_add(1, Ordering::Relaxed);
            c.exceptions.fetch_add(1, Ordering::Relaxed);
            log_refused_write(self.peer);
            return Box::pin(std::future::ready(Err(ExceptionCode::IllegalFunction)));
        }
        let t_ns = monotonic_ns();
        let (mode, result) = self.shared.handle(req.slave, &req.request, t_ns);
        match mode {
            ResponseMode::Delay(d) => Box::pin(async move {
                tokio::time::sleep(d).await;
                result
            }),
            _ => Box::pin(std::future::ready(result)),
        }
    }
}

/// A bound, not yet running plant Modbus server. [`bind`](Self::bind) then
/// [`run`](Self::run); in between, [`local_addr`](Self::local_addr) tells the port when
/// listening on port 0.
#[derive(Debug)]
pub struct PlantServer {
    listener: TcpListener,
    local_addr: SocketAddr,
    shared: Arc<Shared>,
    cfg: ModbusServerConfig,
}

impl PlantServer {
    /// Check the map, build the register image (every Modbus sensor and actuator of `map`,
    /// plus the heartbeat block) and bind `cfg.listen` (with `SO_REUSEADDR`, so a restarted
    /// server can take the port back at once).
    pub async fn bind(
        cfg: &ModbusServerConfig,
        map: &SignalMap,
        snapshots: Arc<SnapshotBoard>,
        commands: Arc<CommandBoard>,
        heartbeat: Arc<HeartbeatBoard>,
    ) -> Result<PlantServer, LinkError> {
        if let Some(hb) = &cfg.heartbeat_register {
            hb.validate()?;
        }
        check_map(map, cfg.heartbeat_register.as_ref())?;
        // the redundant transmitters of a measurement serve the same value (healthy ones)
        let mut sensors = map.modbus_sensors();
        sensors.extend(map.modbus_spares().into_iter().map(|(id, _, b)| (id, b)));
        let actuators = map.modbus_actuators();
        let mut image = RegisterImage::new();
        for (_, b) in &sensors {
            image.map_binding(b);
        }
        for (_, b) in &actuators {
            image.map_binding(b);
        }
        for (_, b) in map.modbus_watchdog() {
            image.map_binding(&b);
        }
        if let Some(hb) = &cfg.heartbeat_register {
            image.map(
                hb.unit_id,
                RegisterTable::Holding,
                hb.address,
                HEARTBEAT_REGISTERS,
            );
        }
        let listener = listen(cfg.listen).map_err(|source| LinkError::Io {
            context: "binding the Modbus server",
            source,
        })?;
        let local_addr = listener.local_addr().map_err(|source| LinkError::Io {
            context: "reading the Modbus server address",
            source,
        })?;
        let state = PlantState {
            snapshot: None,
            sensor_valid: vec![false; sensors.len()],
            writes: 0,
            watched: None,
        };
        Ok(PlantServer {
            listener,
            local_addr,
            cfg: cfg.clone(),
            shared: Arc::new(Shared {
                image: image.into_shared(),
                state: Mutex::new(state),
                sensors,
                actuators,
                heartbeat_register: cfg.heartbeat_register,
                watchdog: map.watchdog.modbus,
                snapshots,
                commands,
                heartbeat,
                counters: Arc::new(PlantCounters::default()),
            }),
        })
    }

    /// The address the server listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The register image, e.g. to inject faults with
    /// [`RegisterImage::set_response_mode`] (a hung or slow device).
    pub fn image(&self) -> SharedImage {
        Arc::clone(&self.shared.image)
    }

    /// Live counters.
    pub fn counters(&self) -> Arc<PlantCounters> {
        Arc::clone(&self.shared.counters)
    }

    /// Serve until `shutdown` completes. On return the listener and every client connection
    /// are closed (connection tasks are cancelled as the server stops).
    ///
    /// Errors: accepting a connection failed (e.g. out of file descriptors).
    pub async fn run(self, shutdown: impl Future<Output = ()>) -> Result<(), LinkError> {
        let server = tokio_modbus::server::tcp::Server::new(self.listener);
        let shared = Arc::clone(&self.shared);
        let counters = Arc::clone(&self.shared.counters);
        let cfg = self.cfg;
        let on_connected = move |stream: TcpStream, peer: SocketAddr| {
            let service = PlantService {
                shared: Arc::clone(&shared),
                may_write: cfg.may_write(peer.ip()),
                peer,
            };
            counters.connections.fetch_add(1, Ordering::Relaxed);
            async move {
                let _ = stream.set_nodelay(true);
                tracing::debug!(target: "modbus", %peer, may_write = service.may_write, "plant server: client connected");
                // malformed requests never reach tokio-modbus's decoder (issue 12, item 9)
                let stream = crate::io::modbus::request_guard::guard_connection(stream, peer);
                Ok(Some((service, stream)))
            }
        };
        let on_error = |e: io::Error| {
            tracing::debug!(target: "modbus", error = %e, "plant server: connection ended");
        };
        tokio::select! {
            r = server.serve(&on_connected, on_error) => r.map_err(|source| LinkError::Io {
                context: "accepting Modbus connections",
                source,
            }),
            () = shutdown => Ok(()),
        }
    }
}

fn listen(addr: SocketAddr) -> io::Result<TcpListener> {
    let socket = match addr {
        SocketAddr::V4(_) => TcpSocket::new_v4()?,
        SocketAddr::V6(_) => TcpSocket::new_v6()?,
    };
    socket.set_reuseaddr(true)?;
    socket.bind(addr)?;
    socket.listen(64)
}

/// Run the plant side of the Modbus link until `shutdown` completes: bind `cfg.listen` and
/// serve the signal map's registers (see [`PlantServer`]).
///
/// Sensor registers follow `snapshots` (re-encoded when a read arrives and a newer snapshot
/// exists; reads of sensors before the first snapshot get exception 0x06 "server device
/// busy", of sensors whose snapshot value is NaN 0x04 "server device failure"). Writes to
/// actuator registers are published into `commands` with their arrival time (monotonic ns),
/// and as controller heartbeats into `heartbeat` (see [`ModbusServerConfig`]).
pub async fn run_plant_server(
    cfg: &ModbusServerConfig,
    map: &SignalMap,
    snapshots: Arc<SnapshotBoard>,
    commands: Arc<CommandBoard>,
    heartbeat: Arc<HeartbeatBoard>,
    shutdown: impl Future<Output = ()>,
) -> Result<(), LinkError> {
    PlantServer::bind(cfg, map, snapshots, commands, heartbeat)
        .await?
        .run(shutdown)
        .await
}
