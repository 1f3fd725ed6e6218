//! Regression test of issue 12, item 9: the 13-byte request
//! `00 01 00 00 00 07 01 0f 00 00 00 10 00` panicked tokio-modbus 0.17's request decoder in
//! the plant node's Modbus TCP server. Now the request guard closes that connection without a
//! panic, and other clients are served as before.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use antisurge::io::modbus::{spawn_tcp_server, RegisterImage, RegisterTable};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

static PANICS: AtomicU64 = AtomicU64::new(0);

async fn exchange(addr: std::net::SocketAddr, request: &[u8]) -> Vec<u8> {
    let mut s = TcpStream::connect(addr).await.expect("connect");
    s.write_all(request).await.expect("write");
    let mut buf = vec![0u8; 300];
    match tokio::time::timeout(Duration::from_secs(2), s.read(&mut buf)).await {
        Ok(Ok(n)) => buf[..n].to_vec(),
        Ok(Err(_)) => Vec::new(),
        Err(_) => panic!("no answer and no close within 2 s for {request:02x?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_write_multiple_coils_closes_the_connection_without_a_panic() {
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        PANICS.fetch_add(1, Ordering::Relaxed);
        default_hook(info);
    }));
    let mut img = RegisterImage::new();
    img.map(1, RegisterTable::Holding, 0, 16);
    let server = spawn_tcp_server("127.0.0.1:0".parse().unwrap(), img.into_shared())
        .await
        .expect("bind");
    let addr = server.local_addr();

    let bad = [
        0x00, 0x01, 0x00, 0x00, 0x00, 0x07, 0x01, 0x0f, 0x00, 0x00, 0x00, 0x10, 0x00,
    ];
    for _ in 0..20 {
        assert!(
            exchange(addr, &bad).await.is_empty(),
            "answered a malformed request"
        );
    }
    // 0x10 with quantity 0x8000: `quantity * 2` overflowed in the decoder
    let overflow = [
        0x00, 0x02, 0x00, 0x00, 0x00, 0x07, 0x01, 0x10, 0x00, 0x00, 0x80, 0x00, 0x00,
    ];
    assert!(exchange(addr, &overflow).await.is_empty());

    // a sound read of 2 holding registers is still answered
    let read = [
        0x00, 0x03, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x00, 0x00, 0x00, 0x02,
    ];
    let answer = exchange(addr, &read).await;
    assert_eq!(&answer[..2], &[0x00, 0x03], "{answer:02x?}");
    assert_eq!(answer[7], 0x03, "{answer:02x?}");
    assert_eq!(answer.len(), 9 + 4, "{answer:02x?}");
    assert_eq!(PANICS.load(Ordering::Relaxed), 0, "the decoder panicked");
}
