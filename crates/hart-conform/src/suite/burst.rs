//! The burst-mode tests (`BURST-`): burst frames on the line, the burst configuration
//! commands and how they refuse what they must.

use hart_host::transport::Transport;
use hart_link::Micros;
use hart_proto::command::{
    BurstCommand, BurstConfiguration, BurstMessageSelect, BurstModeControlRequest, BurstPeriod,
    BurstTrigger, BurstVariables,
};
use hart_proto::frame::{Address, FrameType, MasterKind};
use hart_proto::tables;
use hart_proto::types::{
    hart_nan, BurstModeControl, Classification, HartTime, TriggerMode, UnitCode,
};
use hart_proto::Request;

use crate::catalog::BurstTest;
use crate::runner::{
    cnr, decode, encoded, fail, na, pass, slots, Outcome, Runner, READ_1, WRITE_PROTECTED,
};

impl<T: Transport> Runner<'_, '_, T> {
    /// Runs the burst test `t`.
    pub(crate) async fn burst_test(&mut self, t: BurstTest) -> Outcome {
        let rev = self.dev.revision;
        match t {
            BurstTest::Periods | BurstTest::MasterBits | BurstTest::RequestBetween => {
                self.burst(t).await
            }
            BurstTest::Configuration => self.burst_105().await,
            BurstTest::InvalidMessage
            | BurstTest::PeriodAdjusted
            | BurstTest::TriggerModeRefused
            | BurstTest::CommandRefused
                if rev < 7 =>
            {
                na(format!(
                    "{} is a HART 7 rule (burst message numbers); the device is HART {rev}",
                    t.id()
                ))
            }
            BurstTest::InvalidMessage => self.burst_invalid_message().await,
            BurstTest::PeriodAdjusted => self.burst_period_adjusted().await,
            BurstTest::TriggerModeRefused => self.burst_trigger_mode_refused().await,
            BurstTest::CommandRefused => self.burst_command_refused().await,
        }
    }

    /// Enabled burst messages: (message, command, update period µs, max period µs).
    async fn burst_messages(&mut self) -> Result<Vec<(u8, u16, Micros, Micros)>, Outcome> {
        let mut out = vec![];
        let mut max_msgs = 1u8;
        let mut m = 0u8;
        while m < max_msgs {
            let req = Request::ReadBurstConfiguration(BurstMessageSelect {
                burst_message: (self.dev.revision >= 7).then_some(m),
            });
            let (rc, d, _) = self.read(&req).await?;
            if rc == 64 {
                return Err(na(
                    "command 105 not implemented: the device has no burst mode",
                ));
            }
            let cfg = match burst_periods(rc, &d) {
                Some(x) => x,
                None => {
                    return Err(fail(format!(
                        "command 105 answered response code {rc} with {} bytes",
                        d.len()
                    )))
                }
            };
            let (c, period, max) = cfg;
            max_msgs = c.max_burst_messages.unwrap_or(max_msgs).clamp(1, 8);
            let (period, max) = (period.as_micros(), max.as_micros());
            if matches!(c.control.0, 1 | 3) {
                out.push((m, c.burst_command(), period, max.max(period)));
            }
            m += 1;
            if self.dev.revision < 7 {
                break;
            }
        }
        Ok(out)
    }

    async fn burst(&mut self, t: BurstTest) -> Outcome {
        let msgs = match self.burst_messages().await {
            Ok(m) => m,
            Err(o) => return o,
        };
        if msgs.is_empty() {
            if !self.opts.allow_writes || self.dev.revision < 7 {
                return na(
                    "no burst message is enabled (with --allow-writes the test enables one for itself on a HART 7 device)",
                );
            }
            // Enable message 0 (command 1 every second) for this test, and put it back.
            let original = match self.burst_config(0).await {
                Ok(d) => d,
                Err(o) => return o,
            };
            let second = HartTime::from_millis(1000);
            let steps = [
                Request::WriteBurstCommandNumber(BurstCommand {
                    command_number: 1,
                    burst_message: Some(0),
                }),
                Request::WriteBurstPeriod(BurstPeriod {
                    burst_message: 0,
                    update_period: second,
                    max_update_period: second,
                }),
                Request::WriteBurstTrigger(BurstTrigger {
                    burst_message: 0,
                    trigger_mode: TriggerMode(0),
                    classification: Classification(0),
                    units: UnitCode(250),
                    trigger_level: hart_nan(),
                }),
                Request::BurstModeControl(BurstModeControlRequest {
                    control: BurstModeControl(1),
                    burst_message: Some(0),
                }),
            ];
            if let Err(o) = self.burst_setup(0, &steps).await {
                self.burst_restore(&original).await;
                return o;
            }
            let outcome = self
                .burst_check(t, vec![(0, 1, 1_000_000, 1_000_000)])
                .await;
            let restored = self.burst_restore(&original).await;
            return match (outcome, restored) {
                ((v, d), true) => (v, format!("{d} (message 0 enabled for the test, then restored)")),
                (_, false) => fail(format!(
                    "burst message 0 could not be put back as it was (command 105: {}); set it again",
                    crate::model::hex(&original.1)
                )),
            };
        }
        self.burst_check(t, msgs).await
    }

    /// Configures burst message `m` with `steps` (commands 108, 103, 104 and 109).
    async fn burst_setup(&mut self, m: u8, steps: &[Request]) -> Result<(), Outcome> {
        for req in steps {
            let c = req.command();
            let ex = self.cmd(req).await;
            match ex.rc_data() {
                Some((7, _)) => return Err(cnr(WRITE_PROTECTED)),
                Some((rc, _)) if tables::response_class(rc) == tables::ResponseClass::Error => {
                    return Err(fail(format!(
                        "command {c} (configuring burst message {m}) answered response code {rc}"
                    )))
                }
                Some(_) => {}
                None => return Err(fail(format!("no reply to command {c}"))),
            }
        }
        Ok(())
    }

    /// Puts burst message 0 back as command 105 showed it; true when it reads back so.
    async fn burst_restore(&mut self, original: &(BurstConfiguration, Vec<u8>)) -> bool {
        let Some(steps) = restore_steps(&original.0) else {
            return false;
        };
        for req in &steps {
            let _ = self.cmd(req).await;
        }
        matches!(self.burst_config(0).await, Ok((_, d)) if d == original.1)
    }

    async fn burst_check(&mut self, t: BurstTest, msgs: Vec<(u8, u16, Micros, Micros)>) -> Outcome {
        if t == BurstTest::RequestBetween {
            let ex = self.cmd(&READ_1).await;
            return match ex.reply() {
                Some(_) => pass("a request between burst frames was answered"),
                None => fail("a request while the device bursts got no reply"),
            };
        }
        let longest = msgs.iter().map(|m| m.3).max().unwrap_or(0);
        // Our own requests shift a device's burst cadence for a period or two (a burst
        // frame waits for a slot, then the device catches up): measure after that.
        let settle = 2 * longest;
        let listen = longest * 5 + 2_000_000;
        if listen > self.opts.burst_listen_max {
            return cnr(format!(
                "the burst period ({:.0} s) needs {:.0} s of listening, more than the limit of {:.0} s",
                longest as f64 / 1e6,
                listen as f64 / 1e6,
                self.opts.burst_listen_max as f64 / 1e6
            ));
        }
        let from = self.p.now();
        let frames = self.p.listen(listen, listen).await;
        let to = self.p.now();
        self.p.note_listen(
            &format!(
                "listening for burst frames for {:.1} s",
                listen as f64 / 1e6
            ),
            &frames,
            from,
            to,
        );
        let backs: Vec<(Micros, MasterKind, u16)> = frames
            .iter()
            .filter(|f| f.frame_type() == Some(FrameType::Back))
            .filter_map(|f| {
                let fr = f.frame()?;
                match fr.address {
                    Address::Long(l) if l.id == self.dev.uid => {
                        Some((f.start, fr.address.master(), fr.command))
                    }
                    _ => None,
                }
            })
            .collect();
        if backs.len() < 3 {
            return fail(format!(
                "{} burst frame(s) in {:.1} s with {} message(s) enabled",
                backs.len(),
                listen as f64 / 1e6,
                msgs.len()
            ));
        }
        if t == BurstTest::MasterBits {
            for w in backs.windows(2) {
                if w[0].1 == w[1].1 {
                    return fail(format!(
                        "two consecutive burst frames for the {} master",
                        w[0].1.name()
                    ));
                }
            }
            return pass(format!(
                "{} burst frames, master bits alternating",
                backs.len()
            ));
        }
        // BURST-001: per message (command), intervals within ±10 % of its period.
        let mut worst = 0.0f64;
        for (_, command, period, max) in &msgs {
            let times: Vec<Micros> = backs
                .iter()
                .filter(|b| b.2 == *command && b.0 >= from + settle)
                .map(|b| b.0)
                .collect();
            if times.len() < 2 {
                return fail(format!(
                    "too few burst frames of command {command} in {:.1} s to measure its period of {:.3} s",
                    listen as f64 / 1e6,
                    *period as f64 / 1e6
                ));
            }
            for w in times.windows(2) {
                let dt = w[1] - w[0];
                let lo = *period as f64 * 0.9;
                let hi = *max as f64 * 1.1;
                if (dt as f64) < lo || (dt as f64) > hi {
                    return fail(format!(
                        "command {command}: burst frames {:.3} s apart; the period is {:.3} s (max {:.3} s), ±10 %",
                        dt as f64 / 1e6,
                        *period as f64 / 1e6,
                        *max as f64 / 1e6
                    ));
                }
                worst = worst.max((dt as f64 - *period as f64).abs() / (*period).max(1) as f64);
            }
        }
        pass(format!(
            "{} burst frames at their periods (worst {:.1} % off)",
            backs.len(),
            worst * 100.0
        ))
    }

    /// Command 105 for message `m`: its configuration and reply data, or why not.
    async fn burst_config(&mut self, m: u8) -> Result<(BurstConfiguration, Vec<u8>), Outcome> {
        let req = Request::ReadBurstConfiguration(BurstMessageSelect {
            burst_message: Some(m),
        });
        let (rc, d, _) = self.read(&req).await?;
        if rc == 64 {
            return Err(na(
                "command 105 not implemented: the device has no burst mode",
            ));
        }
        match burst_periods(rc, &d) {
            Some((cfg, _, _)) => Ok((cfg, d)),
            None => Err(fail(format!(
                "command 105 answered response code {rc} with {} bytes",
                d.len()
            ))),
        }
    }

    async fn burst_invalid_message(&mut self) -> Outcome {
        let before = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        // The first message number the device does not have, on purpose.
        let n = before.0.max_burst_messages.unwrap_or(1).max(1);
        let period = HartTime::from_millis(1000);
        let requests = [
            Request::WriteBurstPeriod(BurstPeriod {
                burst_message: n,
                update_period: period,
                max_update_period: period,
            }),
            Request::WriteBurstTrigger(BurstTrigger {
                burst_message: n,
                trigger_mode: TriggerMode(0),
                classification: Classification(0),
                units: UnitCode(250),
                trigger_level: hart_nan(),
            }),
            Request::WriteBurstDeviceVariables(BurstVariables {
                slots: slots(&[250; 8]),
                burst_message: Some(n),
            }),
            Request::WriteBurstCommandNumber(BurstCommand {
                command_number: 1,
                burst_message: Some(n),
            }),
            Request::BurstModeControl(BurstModeControlRequest {
                control: BurstModeControl(0),
                burst_message: Some(n),
            }),
        ];
        for req in requests {
            let c = req.command();
            let ex = self.cmd(&req).await;
            match ex.rc_data() {
                Some((9, _)) => {}
                Some((7, _)) => return cnr(WRITE_PROTECTED),
                Some((rc, _)) => {
                    return fail(format!(
                        "command {c} for burst message {n} (the device has {n}) answered response code {rc}, 9 expected"
                    ))
                }
                None => return fail(format!("no reply to command {c}")),
            }
        }
        match self.burst_config(0).await {
            Ok(after) if after.1 == before.1 => pass(format!(
                "commands 103-109 for message {n}: response code 9, nothing changed"
            )),
            Ok(_) => fail(
                "burst message 0 changed after requests for a message the device does not have",
            ),
            Err(o) => o,
        }
    }

    async fn burst_period_adjusted(&mut self) -> Outcome {
        let before = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        let Some(original) = burst_periods(0, &before.1) else {
            return cnr("command 105 carries no update periods to restore");
        };
        let original = (original.1, original.2);
        // 0.3 s = 9600 in 1/32 ms: between the legal 0.5 s and nothing shorter.
        let asked = HartTime(9600);
        let req = Request::WriteBurstPeriod(BurstPeriod {
            burst_message: 0,
            update_period: asked,
            max_update_period: asked,
        });
        let ex = self.cmd(&req).await;
        if matches!(ex.rc_data(), Some((7, _))) {
            return cnr(WRITE_PROTECTED);
        }
        // The reply's periods, when it carries them.
        let reply = ex.rc_data().map(|(rc, d)| (rc, decode::<BurstPeriod>(&d)));
        let verdict = match reply {
            Some((8, Some(adjusted))) => {
                let got = adjusted.update_period.0;
                const LEGAL: [u32; 7] = [16_000, 32_000, 64_000, 128_000, 256_000, 512_000, 1_024_000];
                if LEGAL.contains(&got) || (1_920_000..=115_200_000).contains(&got) {
                    pass(format!(
                        "0.3 s answered response code 8 and {:.2} s",
                        f64::from(got) / 32_000.0
                    ))
                } else {
                    fail(format!(
                        "0.3 s adjusted to {:.3} s, which is no legal period",
                        f64::from(got) / 32_000.0
                    ))
                }
            }
            Some((rc, _)) if tables::response_class(rc) == tables::ResponseClass::Error => {
                fail(format!("command 103 with 0.3 s answered error response code {rc}; 8 (adjusted) expected"))
            }
            Some((rc, _)) => fail(format!("command 103 with 0.3 s answered response code {rc}, 8 expected")),
            None => fail("no reply to command 103"),
        };
        // Restore the periods.
        let req = Request::WriteBurstPeriod(BurstPeriod {
            burst_message: 0,
            update_period: original.0,
            max_update_period: original.1,
        });
        let ex = self.cmd(&req).await;
        let restored = matches!(ex.rc_data(), Some((0 | 8, _)));
        let back = matches!(self.burst_config(0).await, Ok((_, d)) if burst_periods(0, &d).map(|p| (p.1, p.2)) == Some(original));
        if !(restored && back) {
            return fail(format!(
                "the burst period of message 0 could not be restored: set it again ({})",
                crate::model::hex(&[encoded(&original.0), encoded(&original.1)].concat())
            ));
        }
        verdict
    }

    /// BURST-007: command 104 with trigger mode 5, which Common Table 33 does not define.
    async fn burst_trigger_mode_refused(&mut self) -> Outcome {
        let request = Request::WriteBurstTrigger(BurstTrigger {
            burst_message: 0,
            trigger_mode: TriggerMode(5),
            classification: Classification(0),
            units: UnitCode(250),
            trigger_level: hart_nan(),
        });
        self.burst_write_refused(request, 13, "trigger mode 5 (not in Common Table 33)")
            .await
    }

    /// BURST-008: command 108 with command 6 (write polling address): a write, which no
    /// device bursts.
    async fn burst_command_refused(&mut self) -> Outcome {
        let request = Request::WriteBurstCommandNumber(BurstCommand {
            command_number: 6,
            burst_message: Some(0),
        });
        self.burst_write_refused(request, 2, "command 6 (a write, not burstable)")
            .await
    }

    /// Sends `request` for burst message 0 and expects response code `want` with
    /// message 0's configuration (command 105) unchanged; a configuration the device did
    /// change is written back (command number, then trigger).
    async fn burst_write_refused(&mut self, request: Request, want: u8, what: &str) -> Outcome {
        let command = request.command();
        let before = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        let Some([_, write_command, _, write_trigger, _]) = restore_steps(&before.0) else {
            return cnr(format!(
                "command 105 answered {} bytes, without the trigger (29 for HART 7): nothing to compare",
                before.1.len()
            ));
        };
        let ex = self.cmd(&request).await;
        let verdict = match ex.rc_data() {
            Some((rc, _)) if rc == want => pass(format!(
                "command {command} with {what}: response code {want}"
            )),
            Some((7, _)) => return cnr(WRITE_PROTECTED),
            Some((rc, _)) => fail(format!(
                "command {command} with {what} answered response code {rc}, {want} expected"
            )),
            None => return fail(format!("no reply to command {command}")),
        };
        let after = match self.burst_config(0).await {
            Ok(d) => d,
            Err(o) => return o,
        };
        if after.1 == before.1 {
            return verdict;
        }
        // Put message 0 back as it was: its command first (command 108 may reset the
        // trigger), then its trigger.
        let restored = matches!(self.cmd(&write_command).await.rc_data(), Some((0 | 8, _)))
            && matches!(self.cmd(&write_trigger).await.rc_data(), Some((0 | 8, _)))
            && matches!(self.burst_config(0).await, Ok((_, d)) if d == before.1);
        let changed = format!(
            "command {command} with {what} changed burst message 0 (command 105: {} before, {} after)",
            crate::model::hex(&before.1),
            crate::model::hex(&after.1)
        );
        if restored {
            fail(format!("{changed}; it was written back"))
        } else {
            fail(format!(
                "{changed}; it could not be written back: set its command and trigger again"
            ))
        }
    }

    async fn burst_105(&mut self) -> Outcome {
        let req = Request::ReadBurstConfiguration(BurstMessageSelect {
            burst_message: (self.dev.revision >= 7).then_some(0),
        });
        let (rc, d, _) = match self.read(&req).await {
            Ok(x) => x,
            Err(o) => return o,
        };
        if rc == 64 {
            return na("command 105 not implemented: the device has no burst mode");
        }
        if rc != 0 && rc != 8 {
            return fail(format!(
                "command 105 for message 0 answered response code {rc}"
            ));
        }
        if self.dev.revision >= 7 {
            if d.len() != 29 && d.len() != 27 {
                return fail(format!(
                    "command 105: {} data bytes, 29 (or 27) expected",
                    d.len()
                ));
            }
            let count = decode::<BurstConfiguration>(&d)
                .and_then(|c| c.max_burst_messages)
                .unwrap_or(1);
            let req = Request::ReadBurstConfiguration(BurstMessageSelect {
                burst_message: Some(count),
            });
            let (rc, _, _) = match self.read(&req).await {
                Ok(x) => x,
                Err(o) => return o,
            };
            if rc != 9 {
                return fail(format!(
                    "command 105 for message {count} (the device has {count}) answered response code {rc}, 9 expected"
                ));
            }
            return pass(format!(
                "29-byte configuration; message {count} answered response code 9"
            ));
        }
        pass(format!("command 105: {} data bytes", d.len()))
    }
}

/// A command 105 reply with response code `rc` that carries the update periods (22 bytes
/// and more): the configuration, its update period and its maximum update period.
fn burst_periods(rc: u8, data: &[u8]) -> Option<(BurstConfiguration, HartTime, HartTime)> {
    if tables::response_class(rc) == tables::ResponseClass::Error {
        return None;
    }
    let cfg = decode::<BurstConfiguration>(data)?;
    Some((cfg, cfg.update_period?, cfg.max_update_period?))
}

/// The requests that put burst message 0 back as `cfg` shows it: off first, so that
/// nothing bursts half-configured, then its command (108), periods (103), trigger (104)
/// and control (109). `None` when `cfg` lacks one of them (a reply shorter than the 29
/// bytes of HART 7).
fn restore_steps(cfg: &BurstConfiguration) -> Option<[Request; 5]> {
    Some([
        Request::BurstModeControl(BurstModeControlRequest {
            control: BurstModeControl(0),
            burst_message: Some(0),
        }),
        Request::WriteBurstCommandNumber(BurstCommand {
            command_number: cfg.command_number?.0,
            burst_message: Some(0),
        }),
        Request::WriteBurstPeriod(BurstPeriod {
            burst_message: 0,
            update_period: cfg.update_period?,
            max_update_period: cfg.max_update_period?,
        }),
        Request::WriteBurstTrigger(BurstTrigger {
            burst_message: 0,
            trigger_mode: cfg.trigger_mode?,
            classification: cfg.trigger_classification?,
            units: cfg.trigger_units?,
            trigger_level: cfg.trigger_level?,
        }),
        Request::BurstModeControl(BurstModeControlRequest {
            control: cfg.control,
            burst_message: Some(0),
        }),
    ])
}
