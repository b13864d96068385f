//! The engine's one gate for frames a client composes (HART-IP pass-through, command
//! 77 through the I/O system, the web dashboard's reads): judged by the gateway's rule
//! with the requester's rights, a write audited before it goes and again with the
//! device's answer, a refusal audited and never sent. Against a simulated transmitter
//! in memory, with the audit file read back.

use std::path::Path;

use hart_poller::{
    Denied, Engine, LoopOutcome, Refusal, Requester, Rights, StartOptions, WritePolicy, WriteRecord,
};
use hart_proto::frame::{Address, FrameSpec, MasterKind};

mod common;
use common::{local, transmitter, Setup};

/// The transmitter under `rule`; ready.
async fn engine_under(rule: WritePolicy) -> Engine {
    transmitter(Setup {
        options: StartOptions {
            write_policy: rule,
            ..StartOptions::default()
        },
        ..Setup::default()
    })
    .await
    .0
}

/// The request frame of `command` with `data` to the engine's device, by unique ID.
fn frame_to(engine: &Engine, command: u16, data: &[u8]) -> Vec<u8> {
    let id = engine.image().with(0, |d| d.unique_id()).unwrap().unwrap();
    hart_poller::line::pdu(&FrameSpec::request(
        Address::long(id).with_master(MasterKind::Primary),
        command,
        data,
    ))
}

fn client(rights: Rights) -> Requester {
    Requester {
        rights,
        record: WriteRecord {
            front_end: "hart-ip",
            session: Some(4),
            peer: "10.0.0.5:50211".into(),
            identity: Some("asset-tool".into()),
            via: "token-passing".into(),
            ..WriteRecord::default()
        },
        unwrapped: 0,
    }
}

fn audit_lines(file: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(file)
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn audited(dir: &tempfile::TempDir) -> (WritePolicy, std::path::PathBuf) {
    let file = dir.path().join("audit.jsonl");
    (
        WritePolicy {
            audit: hart_access::Audit::new(Some(file.clone())),
            ..WritePolicy::default()
        },
        file,
    )
}

#[test]
fn a_write_is_audited_with_the_devices_answer() {
    local(async {
        let dir = tempfile::tempdir().unwrap();
        let (rule, file) = audited(&dir);
        let engine = engine_under(rule).await;
        // Damping 2.5 s (command 34), then a value the device sets to the nearest it
        // can or refuses: either way the outcome is the device's own answer.
        let pdu = frame_to(&engine, 34, &2.5f32.to_be_bytes());
        let out = engine.forward(0, pdu, 3, &client(Rights::ReadWrite)).await;
        assert!(matches!(out, Ok(LoopOutcome::Reply(_))), "{out:?}");
        let lines = audit_lines(&file);
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert_eq!(lines[0]["id"], lines[1]["id"]);
        assert!(lines[0]["outcome"].is_null());
        assert_eq!(lines[1]["outcome"], "done");
        assert_eq!(lines[1]["response_code"], 0);
        assert_eq!(lines[1]["command"], 34);
        assert_eq!(lines[1]["front_end"], "hart-ip");
        assert_eq!(lines[1]["identity"], "asset-tool");
        assert_eq!(lines[1]["via"], "token-passing");
        // A loop current the device cannot drive (25 mA): refused by the device, and
        // audited so.
        let pdu = frame_to(&engine, 40, &25.0f32.to_be_bytes());
        let out = engine.forward(0, pdu, 3, &client(Rights::ReadWrite)).await;
        assert!(matches!(out, Ok(LoopOutcome::Reply(_))), "{out:?}");
        let lines = audit_lines(&file);
        assert_eq!(lines.len(), 4, "{lines:?}");
        assert_eq!(lines[3]["outcome"], "refused", "{}", lines[3]);
        assert!(lines[3]["response_code"].as_u64().unwrap() > 0);
        // Reads are not audited.
        let pdu = frame_to(&engine, 1, &[]);
        let out = engine.forward(0, pdu, 3, &client(Rights::ReadWrite)).await;
        assert!(matches!(out, Ok(LoopOutcome::Reply(_))), "{out:?}");
        assert_eq!(audit_lines(&file).len(), 4);
    });
}

#[test]
fn a_read_only_gateway_refuses_and_audits_every_write_and_sends_none() {
    local(async {
        let dir = tempfile::tempdir().unwrap();
        let (rule, file) = audited(&dir);
        let engine = engine_under(WritePolicy {
            read_only: true,
            ..rule
        })
        .await;
        for (command, data) in [
            (34u16, 2.5f32.to_be_bytes().to_vec()),
            (40, 5.0f32.to_be_bytes().to_vec()),
            (18, vec![0; 21]),
            (42, vec![]),
            (130, vec![]), // device-specific: not known to read
        ] {
            let pdu = frame_to(&engine, command, &data);
            let out = engine.forward(0, pdu, 3, &client(Rights::ReadWrite)).await;
            assert!(
                matches!(out, Err(Denied::Policy(Refusal::ReadOnly { .. }))),
                "command {command}: {out:?}"
            );
        }
        let lines = audit_lines(&file);
        assert_eq!(lines.len(), 5, "{lines:?}");
        assert!(lines.iter().all(|l| l["outcome"] == "not-permitted"));
        assert!(lines[0]["reason"].as_str().unwrap().contains("read-only"));
        // Nothing reached the device: its loop current was never fixed.
        assert!(engine
            .image()
            .with(0, |d| d.device_status & 0x08 == 0)
            .unwrap());
        // Reads still go.
        let pdu = frame_to(&engine, 0, &[]);
        let out = engine.forward(0, pdu, 3, &client(Rights::ReadWrite)).await;
        assert!(matches!(out, Ok(LoopOutcome::Reply(_))), "{out:?}");
    });
}

#[test]
fn a_reader_sends_only_reads_and_the_allow_list_holds_for_everyone() {
    local(async {
        let dir = tempfile::tempdir().unwrap();
        let (rule, file) = audited(&dir);
        let engine = engine_under(WritePolicy {
            allow: Some("0-22,48,128-140".parse().unwrap()),
            device_commands: hart_access::DeviceCommands::parse(
                "[[device]]\ntype = \"26F1\"\nreads = \"130\"\n",
            )
            .unwrap(),
            ..rule
        })
        .await;
        let reader = Requester::reader("web", "web dashboard read");
        let pdu = frame_to(&engine, 40, &5.0f32.to_be_bytes());
        let out = engine.forward(0, pdu, 3, &reader).await;
        assert!(matches!(out, Err(Denied::Policy(_))), "{out:?}");
        let pdu = frame_to(&engine, 13, &[]);
        let out = engine.forward(0, pdu, 3, &reader).await;
        assert!(matches!(out, Ok(LoopOutcome::Reply(_))), "{out:?}");
        // A device-specific command the plant declared a read for this device type
        // passes as one (the device may not implement it: it answers all the same);
        // an undeclared one does not.
        let pdu = frame_to(&engine, 130, &[]);
        let out = engine.forward(0, pdu, 3, &reader).await;
        assert!(matches!(out, Ok(LoopOutcome::Reply(_))), "{out:?}");
        let pdu = frame_to(&engine, 131, &[]);
        let out = engine.forward(0, pdu, 3, &reader).await;
        assert!(matches!(out, Err(Denied::Policy(_))), "{out:?}");
        // Not on the allow-list: refused whatever the rights.
        let pdu = frame_to(&engine, 35, &[0; 9]);
        let out = engine.forward(0, pdu, 3, &client(Rights::ReadWrite)).await;
        assert!(
            matches!(
                out,
                Err(Denied::Policy(Refusal::NotListed { command: 35, .. }))
            ),
            "{out:?}"
        );
        // Not a frame at all: nothing sent, and said why.
        let out = engine
            .forward(0, vec![0x82, 1, 2], 3, &client(Rights::ReadWrite))
            .await;
        let Err(why @ Denied::NotAFrame(_)) = out else {
            panic!("{out:?}")
        };
        assert!(why.to_string().contains("cannot judge"), "{why}");
        let lines = audit_lines(&file);
        assert!(lines
            .iter()
            .any(|l| l["command"] == 35 && l["outcome"] == "not-permitted"));
    });
}
