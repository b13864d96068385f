//! The well network's stations fed untrusted bytes: whatever arrives on a line goes
//! through the receiver to a concentrator (as uplink requests, and as replies to its
//! bus requests), a sensor and the handheld's station, and every decoder sees the
//! frames' data; the calibration file parser sees the bytes as text. Nothing may
//! panic, and the concentrator must still answer a good request afterwards.
#![no_main]

use std::cell::RefCell;

use hart_wells::archive::Archive;
use hart_wells::calibration::{CalibrationFile, Sensor};
use hart_wells::concentrator::{Concentrator, ConcentratorConfig};
use hart_wells::handheld::HandheldStation;
use hart_wells::proto::{
    Batch, Groups, Message, Received, Receiver, SegmentRequest, Station, StationStatus,
};
use hart_wells::sensor::{Fault, SensorConfig, SimSensor};
use hart_wells::store::{Durability, Store};
use libfuzzer_sys::fuzz_target;

struct World {
    _dir: tempfile::TempDir,
    conc: Concentrator,
    sensor: SimSensor,
    archive: Archive,
    station: HandheldStation,
    now: u64,
}

thread_local! {
    static WORLD: RefCell<World> = RefCell::new({
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(&dir.path().join("c.db"), 1, 0, Durability::Process).unwrap();
        let now = 1_772_323_200_000;
        World {
            conc: Concentrator::new(ConcentratorConfig::reference(1), store, now).unwrap(),
            sensor: SimSensor::new(SensorConfig {
                address: 1,
                kind: Sensor::Temperature,
                fault: Fault::None,
                seed: 1,
            }),
            archive: Archive::open(&dir.path().join("a.db"), Durability::Process).unwrap(),
            station: HandheldStation::new(),
            _dir: dir,
            now,
        }
    });
}

fuzz_target!(|data: &[u8]| {
    let _ = CalibrationFile::parse(&String::from_utf8_lossy(data));
    WORLD.with(|w| {
        let w = &mut *w.borrow_mut();
        w.now += 61_000;
        let mut rx = Receiver::new();
        for r in rx.feed(data) {
            let Received::Message(m) = r else { continue };
            let _ = Batch::decode(&m.data);
            let _ = Groups::decode(m.status.unwrap_or([0, 0]), &m.data);
            let _ = SegmentRequest::decode(&m.data);
            let _ = StationStatus::decode(m.status.unwrap_or([0, 0]), &m.data);
            // As a request to each station (the uplink is always addressed right).
            let mut up = m.clone();
            up.station = Station::concentrator(1);
            let _ = w.conc.uplink(&up, w.now);
            let _ = w.conc.uplink(&m, w.now);
            let _ = w.sensor.handle(&m, w.now);
            let _ = w.station.answer(&mut w.archive, &m, w.now);
            // As a reply on the bus.
            if w.conc.bus_request(w.now + 20_000).is_some() {
                let _ = w.conc.bus_result(w.now + 20_100, Some(&m));
            }
        }
        let status = Message::request(Station::concentrator(1), 14, vec![]);
        let r = w.conc.uplink(&status, w.now).expect("the concentrator answers its status");
        assert!(r.reply);
    });
});
