//! The Modbus TCP server's request path: the guard (`check_request_adu`) in front of
//! tokio-modbus's request decoder, fed any frame. Whatever the guard lets through must
//! decode without a panic (tokio-modbus 0.17 panics on some frames the guard refuses).
#![no_main]
use antisurge::io::modbus::request_guard::check_request_adu;
use libfuzzer_sys::fuzz_target;
use tokio_modbus::Request;

fuzz_target!(|data: &[u8]| {
    // the MBAP length is made consistent half of the time so that most inputs reach the PDU
    let mut adu = data.to_vec();
    if adu.len() >= 8 && adu.len() <= 260 && adu[0] & 1 == 0 {
        let len = (adu.len() - 6) as u16;
        adu[4..6].copy_from_slice(&len.to_be_bytes());
    }
    if check_request_adu(&adu).is_ok() {
        let _ = Request::try_from(bytes::Bytes::copy_from_slice(&adu[7..]));
    }
});
