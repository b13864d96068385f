//! HART-IP version 2 security, fed untrusted input: PSK files and `--psk` values, the
//! sorting of datagrams on a DTLS port, and a TLS server handshake (our PSK callback
//! and refusal naming around OpenSSL) given arbitrary client bytes. Nothing may panic.
#![no_main]

use std::sync::{Arc, OnceLock};

use libfuzzer_sys::fuzz_target;
use tokio::io::AsyncWriteExt;

fn context() -> &'static openssl::ssl::SslContext {
    static CTX: OnceLock<openssl::ssl::SslContext> = OnceLock::new();
    CTX.get_or_init(|| {
        let keys = hart_ip_tls::PskTable::parse("fuzz:00112233445566778899aabbccddeeff").unwrap();
        hart_ip_tls::server_context(Arc::new(keys), false).unwrap()
    })
}

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let _ = hart_ip_tls::PskTable::parse(&text);
    let _ = hart_ip_tls::Psk::parse(&text);
    let _ = hart_ip_tls::classify(data);
    // A server handshake over an in-memory pipe: the fuzzer is the client.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .unwrap();
    rt.block_on(async {
        let (mut client, server) = tokio::io::duplex(1 << 16);
        let _ = client.write_all(data).await;
        drop(client);
        let Ok((ssl, note)) = hart_ip_tls::server_ssl(context(), false) else {
            return;
        };
        let mut stream = hart_ip_tls::SslStream::new(ssl, server).unwrap();
        let r = tokio::time::timeout(
            std::time::Duration::from_millis(50),
            std::pin::Pin::new(&mut stream).accept(),
        )
        .await;
        if let Ok(Err(e)) = r {
            let n = note.lock().map(|n| n.clone()).unwrap_or_default();
            let _ = hart_ip_tls::refusal(&n, &e, data.first().copied()).to_string();
        }
    });
});
