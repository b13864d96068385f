//! Sound card input (`modem rx --sound-card`, cargo feature `sound-card`) through real
//! ALSA with no sound card: ALSA's `file` plugin on a `null` device, reading a raw
//! recording made by `modem tx`, is made the default input by an `asoundrc` under
//! `XDG_CONFIG_HOME` (which libasound reads). cpal opens it as it would a card.
#![cfg(feature = "sound-card")]

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

mod common;
use common::Kill;

const FRAMES: [&str; 2] = ["0280000082", "82A606BC614E0100B0"];

#[test]
fn frames_from_the_default_sound_card_input() {
    let bin = env!("CARGO_BIN_EXE_hartkit");
    let dir = std::env::temp_dir().join(format!("hartkit-sound-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("alsa")).unwrap();
    // The recording, raw s16le at 48 kHz mono, ten times over.
    let one = Command::new(bin)
        .args(["modem", "tx", "--out", "-", FRAMES[0], FRAMES[1]])
        .output()
        .unwrap();
    assert!(one.status.success());
    let raw = dir.join("in.raw");
    std::fs::write(&raw, one.stdout.repeat(10)).unwrap();
    std::fs::write(
        dir.join("alsa/asoundrc"),
        format!(
            "pcm.hartfile {{ type file slave.pcm \"null\" file \"/dev/null\" infile \"{}\" format \"raw\" }}\n\
             pcm.!default {{ type plug slave {{ pcm \"hartfile\" format S16_LE rate 48000 channels 1 }} }}\n",
            raw.display()
        ),
    )
    .unwrap();
    // The null device never ends: the guard kills the decoder whatever happens here,
    // a failed assertion included.
    let mut child = Kill(
        Command::new(bin)
            .args(["modem", "rx", "--sound-card", "default", "--json"])
            .env("XDG_CONFIG_HOME", &dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let stdout = child.0.stdout.take().unwrap();
    let mut got = vec![];
    for line in BufReader::new(stdout).lines().take(6) {
        let v: serde_json::Value = serde_json::from_str(&line.unwrap()).unwrap();
        got.push(v["hex"].as_str().unwrap().to_string());
        assert_eq!(v["checksum_ok"], true, "{v}");
    }
    drop(child);
    let _ = std::fs::remove_dir_all(&dir);
    // The card's own rate may differ from the recording's (ALSA's plug converts).
    assert_eq!(got, [FRAMES[0], FRAMES[1]].repeat(3));
}

#[test]
fn a_card_that_is_not_there_is_named() {
    let out = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args(["modem", "rx", "--sound-card", "no-such-card"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no sound card input named \"no-such-card\""),
        "{err}"
    );
}
