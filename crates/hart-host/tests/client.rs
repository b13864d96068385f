//! The client against the in-process plant, in virtual time.

use hart_host::target::{open, AnyTransport};
use hart_host::{Client, DeviceRef, HostError};

fn client() -> Client<AnyTransport> {
    Client::new(open("sim?virtual").unwrap())
}

#[tokio::test(flavor = "current_thread")]
async fn scan_finds_every_device_of_the_demo_plant() {
    let mut c = client();
    let found = c.scan(0..=20, |_| {}).await.unwrap();
    let polls: Vec<u8> = found.iter().map(|d| d.polling_address.unwrap()).collect();
    assert_eq!(polls, vec![1, 2, 3, 17]);
    assert_eq!(found[0].tag.as_deref(), Some("PT-100"));
    assert_eq!(found[1].tag.as_deref(), Some("TT-200"));
    assert_eq!(found[0].revision(), 7);
}

#[tokio::test(flavor = "current_thread")]
async fn commands_by_poll_tag_and_unique_id() {
    let mut c = client();
    let d = c.resolve(&DeviceRef::Poll(3)).await.unwrap();
    let r = c.command(&d, 1, &[]).await.unwrap();
    assert_eq!(r.data[0], 57, "valve travel in %");
    let t = c.resolve(&DeviceRef::Tag("TT-200".into())).await.unwrap();
    assert_eq!(
        t.unique_id(),
        c.resolve(&DeviceRef::Poll(2)).await.unwrap().unique_id()
    );
    let u = c
        .resolve(&DeviceRef::UniqueId(d.unique_id()))
        .await
        .unwrap();
    assert_eq!(u.identity.device_id, d.identity.device_id);
}

#[test]
fn no_reply_hints_fit_the_port() {
    let e = |port: &str| {
        HostError::NoReply {
            target: "polling address 3".into(),
            attempts: 4,
            sto_ms: 256,
            port: port.into(),
        }
        .to_string()
    };
    assert!(e("serial /dev/ttyUSB0 at 1200 bit/s").contains("RTS"));
    assert!(e("RS-485 /dev/ttyUSB1 at 19200 bit/s").contains("A and B"));
    assert!(e("HART-IP udp 10.0.0.5:5094").contains("server still running"));
    let behind = HostError::NoReplyBehindServer {
        target: "polling address 3".into(),
        port: "HART-IP tcp 10.0.0.5:5094".into(),
        status: "HART-IP status 6: device-specific error".into(),
    };
    assert_eq!(behind.exit_code(), 3);
    assert!(behind.to_string().contains("did not answer on its loop"));
}

#[tokio::test(flavor = "current_thread")]
async fn errors_explain_themselves() {
    let mut c = client();
    match c.resolve(&DeviceRef::Poll(9)).await {
        Err(e @ HostError::NoReply { .. }) => {
            let msg = e.to_string();
            assert!(
                msg.contains("no reply from polling address 9 after 2 tries")
                    || msg.contains("no reply from polling address 9 after 4 tries"),
                "{msg}"
            );
            // A simulated plant has no modem: no hint about RTS.
            assert!(msg.ends_with("is a device at that address?"), "{msg}");
            assert_eq!(e.exit_code(), 3);
        }
        other => panic!("{other:?}"),
    }
    let d = c.resolve(&DeviceRef::Poll(1)).await.unwrap();
    match c.command(&d, 200, &[]).await {
        Err(e @ HostError::Device { code: 64, .. }) => {
            assert!(e.to_string().contains("command not implemented"), "{e}")
        }
        other => panic!("{other:?}"),
    }
}

#[tokio::test(flavor = "current_thread")]
async fn bursts_are_collected_while_listening() {
    let mut c = client();
    c.listen(10_000_000).await.unwrap();
    let bursts = c.take_bursts();
    assert!(
        bursts.len() >= 4,
        "temperature transmitter bursts every 2 s: {}",
        bursts.len()
    );
}

/// The demo plant on the analog loop: every character through a modulator, the loop
/// and a demodulator.
fn analog_client(cable_m: u32) -> Client<AnyTransport> {
    Client::new(open(&format!("sim?virtual&medium=analog&cable_m={cable_m}")).unwrap())
}

#[tokio::test(flavor = "current_thread")]
async fn the_demo_plant_on_the_analog_loop() {
    let mut c = analog_client(1000);
    let found = c.scan(0..=20, |_| {}).await.unwrap();
    let polls: Vec<u8> = found.iter().map(|d| d.polling_address.unwrap()).collect();
    assert_eq!(polls, vec![1, 2, 3, 17]);
    let d = c.resolve(&DeviceRef::Poll(3)).await.unwrap();
    let r = c.command(&d, 1, &[]).await.unwrap();
    assert_eq!(r.data[0], 57, "valve travel in %");
    c.listen(6_000_000).await.unwrap();
    assert!(
        c.take_bursts().len() >= 2,
        "the temperature transmitter's bursts"
    );
}

#[tokio::test(flavor = "current_thread")]
async fn on_too_long_a_cable_no_device_is_heard() {
    // 8 km of 100 pF/m: the devices' 1 mApp reaches the control room under carrier
    // detect.
    let mut c = analog_client(8000);
    let found = c.scan(1..=3, |_| {}).await.unwrap();
    assert!(found.is_empty(), "{found:?}");
}
