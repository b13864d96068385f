//! The pipelined HART-IP session against a scripted server that answers out of order.

use std::sync::Arc;
use std::time::Duration;

use hart_host::hartip::HartIpSession;
use hart_ip::{encode, Message, MessageId, MessageType};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpListener;

fn msg(ty: MessageType, id: MessageId, status: u8, seq: u16, body: &[u8]) -> Vec<u8> {
    let mut b = vec![0u8; 8 + body.len()];
    encode(1, ty, id, status, seq, body, &mut b).unwrap();
    b
}

/// Three requests in flight on one TCP session; the server holds them, answers them in
/// reverse order with a publish message in between, and reports the second device
/// absent: each request gets its own answer.
#[tokio::test(flavor = "current_thread")]
async fn replies_find_their_requests_in_any_order() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let server = tokio::spawn(async move {
        let (mut s, _) = listener.accept().await.unwrap();
        let mut buf = vec![];
        let mut requests = vec![];
        let mut tmp = [0u8; 512];
        while requests.len() < 4 {
            let n = s.read(&mut tmp).await.unwrap();
            buf.extend_from_slice(&tmp[..n]);
            while let Ok((m, used)) = Message::parse(&buf) {
                let (h, body) = (m.header, m.body.to_vec());
                buf.drain(..used);
                if h.message_id == MessageId::SessionInitiate {
                    s.write_all(&msg(
                        MessageType::Response,
                        h.message_id,
                        0,
                        h.sequence,
                        &body,
                    ))
                    .await
                    .unwrap();
                } else {
                    requests.push((h.sequence, body));
                }
                if requests.len() == 4 {
                    break;
                }
            }
        }
        // Session initiate was 1; the requests are 2, 3, 4 (and 5, answered last).
        let seqs: Vec<u16> = requests.iter().map(|r| r.0).collect();
        assert_eq!(seqs, [2, 3, 4, 5]);
        let publish = msg(
            MessageType::Publish,
            MessageId::TokenPassingPdu,
            0,
            1,
            &[0x81, 0xAA],
        );
        for (seq, body) in requests[..3].iter().rev() {
            // The "reply" echoes the request with its last byte changed; request 3
            // stands for a device that did not answer.
            let mut reply = body.clone();
            *reply.last_mut().unwrap() ^= 0xFF;
            let (st, reply) = if *seq == 3 { (6, vec![]) } else { (0, reply) };
            s.write_all(&msg(
                MessageType::Response,
                MessageId::TokenPassingPdu,
                st,
                *seq,
                &reply,
            ))
            .await
            .unwrap();
            s.write_all(&publish).await.unwrap();
        }
        // A response nobody waits for (a stale sequence number) changes nothing.
        s.write_all(&msg(
            MessageType::Response,
            MessageId::TokenPassingPdu,
            0,
            99,
            &[1],
        ))
        .await
        .unwrap();
        let (seq, body) = &requests[3];
        s.write_all(&msg(
            MessageType::Response,
            MessageId::TokenPassingPdu,
            0,
            *seq,
            body,
        ))
        .await
        .unwrap();
        // Keep the connection until the client is done.
        let _ = s.read(&mut tmp).await;
    });
    let session = Arc::new(
        HartIpSession::connect(&addr.to_string(), true, 60_000)
            .await
            .unwrap(),
    );
    assert_eq!(session.timer_ms(), 60_000);
    let mut tasks = vec![];
    for k in 0..3u8 {
        let session = session.clone();
        tasks.push(tokio::spawn(async move {
            let pdu = [0x02, 0x80 | k, 0x00, 0x00, 0x82 ^ (0x80 | k)];
            (pdu, session.request(&pdu, Duration::from_secs(5)).await)
        }));
        // Keep the order of sequence numbers predictable.
        tokio::task::yield_now().await;
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(session.in_flight(), 3, "three requests in flight at once");
    let last = {
        let session = session.clone();
        tokio::spawn(async move {
            session
                .request(&[0x02, 0x84, 0x00, 0x00, 0x06], Duration::from_secs(5))
                .await
        })
    };
    let mut answers = vec![];
    for t in tasks {
        answers.push(t.await.unwrap());
    }
    assert_eq!(last.await.unwrap().unwrap(), [0x02, 0x84, 0x00, 0x00, 0x06]);
    for (pdu, answer) in answers {
        if pdu[1] == 0x81 {
            let e = answer.unwrap_err();
            assert_eq!(e.kind(), std::io::ErrorKind::NotFound);
            assert!(e.to_string().contains("no reply from the device"), "{e}");
        } else {
            let mut expect = pdu.to_vec();
            *expect.last_mut().unwrap() ^= 0xFF;
            assert_eq!(answer.unwrap(), expect);
        }
    }
    for _ in 0..3 {
        assert_eq!(session.next_publish().await.unwrap(), [0x81, 0xAA]);
    }
    assert_eq!(session.in_flight(), 0);
    drop(session);
    server.abort();
}
