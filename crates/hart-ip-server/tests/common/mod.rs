//! What the server's tests share.
#![allow(dead_code)]

use hart_proto::frame::{Address, FrameBuf, FrameSpec};

/// Runs `test` on a current-thread runtime inside a `LocalSet`, as the server's tasks
/// need.
pub fn run(test: impl std::future::Future<Output = ()>) {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    tokio::task::LocalSet::new().block_on(&rt, test);
}

/// A request PDU (hart-proto extends commands above 255 itself).
pub fn frame(address: Address, command: u16, data: &[u8]) -> Vec<u8> {
    FrameBuf::encode(&FrameSpec::request(address, command, data))
        .unwrap()
        .as_slice()
        .to_vec()
}
