//! Byte-scripted tests of each DP service: request bytes in, reply bytes out.
//!
//! Sources of the layouts the vectors follow:
//! * [FDL] telegram formats SD1/SD2/SD3/SD4/SC, LE = DU + 3, FCS = sum of DA..DU:
//!   Kipp & Zonen COMBILOG 1022 hardware manual, p. 118 ("Start-Delimiter (SD) in the
//!   PROFIBUS-protocol", LE/LEr), and the telegram table of the Balluff BTL7-T500
//!   configuration guide (Tab. 4-15: `68 LE LE 68 DA SA FC DSAP SSAP DU FCS 16`).
//! * [SAP] DP SAPs 55..62 and their data units (Set_Prm bytes 0..6, Global_Control
//!   `GC_Command, Group_Select`): ABB FPBA-01 user manual, "Communication protocol",
//!   pp. 121-122; Global_Control bits: profichip VPC3+C user manual rev. 1.03, fig.
//!   6-16, p. 51.
//! * [DIAG] Diagnosis bytes 0..5 (station status 1-3, master address, ident number)
//!   and the device-related block header (`00xxxxxx`, length including the header):
//!   ABB RPBA-01 manual p. 44, ABB FPBA-01 manual p. 125.
//! * [PR] Telegrams profirust 0.6.0's DP master (an independent implementation)
//!   sent on its simulated bus in `tests/profirust_master.rs`, copied from that run.

use std::time::Duration;

use hart_profibus::{DpState, Slave, SlaveConfig};

const US: u8 = 5;
const IDENT: u16 = 0x4854;

/// One output module of 2 bytes (0xA1), one input module of 1 byte (0x90).
fn slave() -> Slave {
    Slave::new(SlaveConfig {
        address: US,
        ident_number: IDENT,
        cfg: vec![0xA1, 0x90],
        baud: 19_200,
        max_tsdr_bits: 60,
        user_prm_len: 0,
    })
    .unwrap()
}

struct Script {
    slave: Slave,
    now: Duration,
}

impl Script {
    fn new() -> Script {
        Script {
            slave: slave(),
            now: Duration::from_secs(1),
        }
    }

    /// Sends `req` and returns the reply due after the station delay (none if none).
    fn send(&mut self, req: &[u8]) -> Option<Vec<u8>> {
        self.now += Duration::from_millis(20);
        self.slave.receive(self.now, req);
        // Not before min TSDR (11 bit times at 19200 bit/s = 573 µs).
        assert_eq!(self.slave.poll_transmit(self.now), None, "sent at once");
        self.now += Duration::from_micros(600);
        self.slave.poll_transmit(self.now)
    }
}

/// FCS of the SD2 body and the end delimiter, appended.
fn sd2(body: &[u8]) -> Vec<u8> {
    let le = body.len() as u8;
    let mut t = vec![0x68, le, le, 0x68];
    t.extend_from_slice(body);
    t.push(body.iter().fold(0u8, |a, b| a.wrapping_add(*b)));
    t.push(0x16);
    t
}

// [FDL][SAP] Slave_Diag request, master 2 to station 5, SRD high with FCB: DA 0x85
// (5 + SAP extension), SA 0x82, FC 0x6D, DSAP 60, SSAP 62.
const DIAG_REQ: [u8; 11] = [
    0x68, 0x05, 0x05, 0x68, 0x85, 0x82, 0x6D, 0x3C, 0x3E, 0xEE, 0x16,
];
// [SAP][PR] Set_Prm: Lock_Req + WD_On (0x88), watchdog 1 × 20 × 10 ms, min TSDR 11,
// ident 0x4854, group 0, no user parameters (profirust sent this with FC 0x5C).
const SET_PRM: [u8; 18] = [
    0x68, 0x0C, 0x0C, 0x68, 0x85, 0x82, 0x5D, 0x3D, 0x3E, 0x88, 0x01, 0x14, 0x0B, 0x48, 0x54, 0x00,
    0x23, 0x16,
];
// [SAP] Chk_Cfg with our identifiers A1 90.
const CHK_CFG: [u8; 13] = [
    0x68, 0x07, 0x07, 0x68, 0x85, 0x82, 0x7D, 0x3E, 0x3E, 0xA1, 0x90, 0x31, 0x16,
];

#[test]
fn fdl_status_is_answered_for_live_lists() {
    // [FDL] SD1 request FDL status (FC 0x49), reply SD1 FC 0x00 (slave, OK).
    let mut s = Script::new();
    let reply = s.send(&[0x10, 0x05, 0x02, 0x49, 0x50, 0x16]).unwrap();
    assert_eq!(reply, [0x10, 0x02, 0x05, 0x00, 0x07, 0x16]);
}

#[test]
fn diagnosis_before_parameters() {
    // [DIAG][PR] SD3 reply (8 bytes: two SAPs + six diagnosis bytes), FC 0x08 (DL):
    // station not ready (0x02), Prm_Req + the permanent bit (0x05), no master (0xFF),
    // ident 0x4854. profirust's master received exactly these bytes.
    let mut s = Script::new();
    let reply = s.send(&DIAG_REQ).unwrap();
    assert_eq!(
        reply,
        [0xA2, 0x82, 0x85, 0x08, 0x3E, 0x3C, 0x02, 0x05, 0x00, 0xFF, 0x48, 0x54, 0x2B, 0x16]
    );
}

#[test]
fn data_exchange_before_parameters_is_refused() {
    // [FDL] Data_Exchange (no SAPs, SRD high) in Wait_Prm: reply SD1 with status RS
    // (0x03, service access point not activated).
    let mut s = Script::new();
    let reply = s.send(&sd2(&[0x05, 0x02, 0x7D, 0x11, 0x22])).unwrap();
    assert_eq!(reply, [0x10, 0x02, 0x05, 0x03, 0x0A, 0x16]);
}

#[test]
fn parameters_configuration_data_exchange() {
    let mut s = Script::new();
    s.slave.set_inputs(&[0x42]);
    assert_eq!(s.send(&SET_PRM).unwrap(), [0xE5]);
    assert_eq!(s.slave.state(), DpState::WaitCfg);
    assert_eq!(s.slave.watchdog(), Some(Duration::from_millis(200)));
    assert_eq!(s.send(&CHK_CFG).unwrap(), [0xE5]);
    assert_eq!(s.slave.state(), DpState::DataExch);

    // The first Data_Exchange says "data high" (DH, FC 0x0A): new diagnosis to fetch.
    let reply = s.send(&sd2(&[0x05, 0x02, 0x5D, 0x11, 0x22])).unwrap();
    assert_eq!(reply, sd2(&[0x02, 0x05, 0x0A, 0x42]));
    assert_eq!(s.slave.outputs(), [0x11, 0x22]);
    // Diagnosis: ready, master 2, watchdog on (0x0C = permanent + WD_On).
    let reply = s.send(&DIAG_REQ).unwrap();
    assert_eq!(
        reply,
        [0xA2, 0x82, 0x85, 0x08, 0x3E, 0x3C, 0x00, 0x0C, 0x00, 0x02, 0x48, 0x54, 0x33, 0x16]
    );
    // Then "data low" (DL, FC 0x08).
    let reply = s.send(&sd2(&[0x05, 0x02, 0x7D, 0x33, 0x44])).unwrap();
    assert_eq!(reply, sd2(&[0x02, 0x05, 0x08, 0x42]));

    // A repeated request (same FCB) gets the same reply and is not applied twice.
    s.slave.set_inputs(&[0x43]);
    let again = s.send(&sd2(&[0x05, 0x02, 0x7D, 0x55, 0x66])).unwrap();
    assert_eq!(again, sd2(&[0x02, 0x05, 0x08, 0x42]));
    assert_eq!(s.slave.outputs(), [0x33, 0x44]);
    assert_eq!(s.slave.stats().repeats, 1);

    // Get_Cfg (SAP 59) returns our identifiers; RD_Inp (56) and RD_Outp (57) the image,
    // to any master.
    let get_cfg = sd2(&[0x85, 0x82, 0x6D, 59, 62]);
    assert_eq!(
        s.send(&get_cfg).unwrap(),
        sd2(&[0x82, 0x85, 0x08, 62, 59, 0xA1, 0x90])
    );
    let rd_inp = sd2(&[0x85, 0x83, 0x4C, 56, 62]);
    assert_eq!(
        s.send(&rd_inp).unwrap(),
        sd2(&[0x83, 0x85, 0x08, 62, 56, 0x43])
    );
    let rd_outp = sd2(&[0x85, 0x83, 0x4C, 57, 62]);
    assert_eq!(
        s.send(&rd_outp).unwrap(),
        sd2(&[0x83, 0x85, 0x08, 62, 57, 0x33, 0x44])
    );
    // Another master's Data_Exchange is refused (RS); its diagnosis shows Master_Lock.
    assert_eq!(
        s.send(&sd2(&[0x05, 0x03, 0x7D, 0, 0])).unwrap(),
        [0x10, 0x03, 0x05, 0x03, 0x0B, 0x16]
    );
    assert_eq!(s.slave.diagnosis(Some(3))[0], 0x80);
    // Another master's Set_Prm is ignored while we are locked.
    let mut other = SET_PRM;
    other[5] = 0x83;
    other[16] = other[16].wrapping_add(1);
    assert_eq!(s.send(&other).unwrap(), [0xE5]);
    assert_eq!(s.slave.master(), Some(2));
}

#[test]
fn global_control_freeze_sync_clear() {
    let mut s = Script::new();
    s.send(&SET_PRM);
    s.send(&CHK_CFG);
    s.slave.set_inputs(&[1]);
    s.send(&sd2(&[0x05, 0x02, 0x5D, 0x10, 0x10]));
    // [SAP] Global_Control broadcast (DA 127), SDN (FC 0x44), Freeze (0x08), all
    // groups: no reply; inputs are frozen.
    let gc = |cmd: u8| sd2(&[0xFF, 0x82, 0x44, 58, 62, cmd, 0]);
    assert_eq!(s.send(&gc(0x08)), None);
    s.slave.set_inputs(&[2]);
    let reply = s.send(&sd2(&[0x05, 0x02, 0x7D, 0x10, 0x10])).unwrap();
    assert_eq!(reply[reply.len() - 3], 1, "frozen inputs");
    assert_eq!(s.slave.diagnosis(Some(2))[1] & 0x10, 0x10, "Freeze_Mode");
    assert_eq!(s.send(&gc(0x04)), None);
    let reply = s.send(&sd2(&[0x05, 0x02, 0x5D, 0x10, 0x10])).unwrap();
    assert_eq!(reply[reply.len() - 3], 2, "unfrozen");

    // Sync: outputs are held until the next Sync.
    s.send(&gc(0x20));
    s.send(&sd2(&[0x05, 0x02, 0x7D, 0x20, 0x20]));
    assert_eq!(s.slave.outputs(), [0x10, 0x10]);
    s.send(&gc(0x20));
    assert_eq!(s.slave.outputs(), [0x20, 0x20]);
    s.send(&gc(0x10));
    s.send(&sd2(&[0x05, 0x02, 0x5D, 0x30, 0x30]));
    assert_eq!(s.slave.outputs(), [0x30, 0x30]);

    // A group we are not in: ignored. Clear_Data: outputs zero.
    s.send(&sd2(&[0xFF, 0x82, 0x44, 58, 62, 0x02, 0x04]));
    assert_eq!(s.slave.outputs(), [0x30, 0x30]);
    s.send(&gc(0x02));
    assert_eq!(s.slave.outputs(), [0, 0]);
}

#[test]
fn faults_are_in_the_diagnosis() {
    let mut s = Script::new();
    // Wrong ident number (0x1234): acknowledged, then Prm_Fault in the diagnosis.
    let mut wrong = SET_PRM;
    wrong[13] = 0x12;
    wrong[14] = 0x34;
    wrong[16] = wrong[16]
        .wrapping_sub(0x48 + 0x54)
        .wrapping_add(0x12 + 0x34);
    assert_eq!(s.send(&wrong).unwrap(), [0xE5]);
    let d = s.slave.diagnosis(Some(2));
    assert_eq!(d[0], 0x42, "Prm_Fault + not ready");
    assert_eq!(s.slave.state(), DpState::WaitPrm);
    // Right parameters (the next request: FCB toggled, FC 0x7D), wrong configuration:
    // Cfg_Fault, back to Wait_Prm.
    let mut next = SET_PRM;
    next[6] = 0x7D;
    next[16] = next[16].wrapping_add(0x20);
    s.send(&next);
    assert_eq!(s.slave.state(), DpState::WaitCfg);
    assert_eq!(
        s.send(&sd2(&[0x85, 0x82, 0x5D, 62, 62, 0x90])).unwrap(),
        [0xE5]
    );
    let d = s.slave.diagnosis(Some(2));
    assert_eq!(d[0], 0x06, "Cfg_Fault + not ready");
    assert_eq!(d[1] & 0x01, 0x01, "Prm_Req");
    assert_eq!(s.slave.state(), DpState::WaitPrm);
}

#[test]
fn the_watchdog_clears_the_outputs() {
    let mut s = Script::new();
    s.send(&SET_PRM);
    s.send(&CHK_CFG);
    s.send(&sd2(&[0x05, 0x02, 0x5D, 0x11, 0x22]));
    assert_eq!(s.slave.outputs(), [0x11, 0x22]);
    let due = s.slave.deadline().unwrap();
    assert_eq!(
        due,
        s.now - Duration::from_micros(600) + Duration::from_millis(200)
    );
    assert_eq!(s.slave.poll_transmit(due - Duration::from_millis(1)), None);
    assert_eq!(s.slave.state(), DpState::DataExch);
    assert_eq!(s.slave.poll_transmit(due), None);
    assert_eq!(s.slave.state(), DpState::WaitPrm);
    assert_eq!(s.slave.outputs(), [0, 0]);
}

#[test]
fn other_stations_tokens_and_damage_are_not_answered() {
    let mut s = Script::new();
    // [FDL] Another station's request, a token (SD4), a short acknowledgement.
    assert_eq!(s.send(&[0x10, 0x06, 0x02, 0x49, 0x51, 0x16]), None);
    assert_eq!(s.send(&[0xDC, 0x03, 0x02]), None);
    assert_eq!(s.send(&[0xE5]), None);
    // A damaged FCS: not answered, and the rest of the burst is ignored too.
    let mut bad = DIAG_REQ.to_vec();
    bad[9] ^= 0x01;
    bad.extend_from_slice(&DIAG_REQ);
    assert_eq!(s.send(&bad), None);
    assert_eq!(s.slave.stats().damaged, 1);
    // After an idle line (33 bit times), the next request is answered.
    assert!(s.send(&DIAG_REQ).is_some());
    // A request cut short, then silence: dropped; the next one is answered.
    s.send(&DIAG_REQ[..6]);
    s.now += Duration::from_millis(5);
    assert_eq!(s.slave.poll_transmit(s.now), None);
    assert_eq!(s.slave.stats().cut_short, 1);
    assert!(s.send(&DIAG_REQ).is_some());
    // A request split over reads is one request.
    s.now += Duration::from_millis(20);
    s.slave.receive(s.now, &DIAG_REQ[..4]);
    s.slave
        .receive(s.now + Duration::from_micros(500), &DIAG_REQ[4..]);
    assert!(s
        .slave
        .poll_transmit(s.now + Duration::from_millis(2))
        .is_some());
}

#[test]
fn device_diagnosis_block_names_devices() {
    let mut s = Script::new();
    s.send(&SET_PRM);
    s.send(&CHK_CFG);
    s.send(&sd2(&[0x05, 0x02, 0x5D, 0, 0]));
    s.send(&DIAG_REQ);
    // Devices 0 and 9 do not answer: a device-related block of 3 bytes (header 0x03).
    s.slave.set_unit_diag(&[0x01, 0x02]);
    let reply = s.send(&sd2(&[0x05, 0x02, 0x7D, 0, 0])).unwrap();
    assert_eq!(reply[6], 0x0A, "data high: diagnosis waiting");
    let reply = s.send(&DIAG_REQ).unwrap();
    assert_eq!(
        reply,
        sd2(&[0x82, 0x85, 0x08, 0x3E, 0x3C, 0x08, 0x0C, 0x00, 0x02, 0x48, 0x54, 0x03, 0x01, 0x02])
    );
}

#[test]
fn a_host_s_bursts_do_not_cut_a_request() {
    // Behind a USB adapter a request may come in two reads 16 ms apart: with a partial
    // timeout of 50 ms it is one request; with the line's TSYN it would be cut.
    let mut s = Script::new();
    s.slave.set_partial_timeout(Duration::from_millis(50));
    s.now += Duration::from_millis(20);
    s.slave.receive(s.now, &DIAG_REQ[..5]);
    s.now += Duration::from_millis(16);
    assert_eq!(s.slave.poll_transmit(s.now), None);
    s.slave.receive(s.now, &DIAG_REQ[5..]);
    s.now += Duration::from_millis(1);
    assert!(s.slave.poll_transmit(s.now).is_some());
    assert_eq!(s.slave.stats().cut_short, 0);
}
