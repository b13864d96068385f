//! A sound card as a sample source for `hartkit modem rx --sound-card NAME`: the first
//! channel of the card's input at its own rate, in blocks, through the `cpal` crate.
//! Built with the cargo feature `sound-card` (on Linux it needs the ALSA headers,
//! `libasound2-dev`); without it, opening a card says how to get it.

/// How long the card may stay silent (no samples at all, not quiet samples) before
/// the input is taken as gone.
pub const STALL_SECONDS: u64 = 5;

#[cfg(feature = "sound-card")]
mod imp {
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::sync::{mpsc, Arc};
    use std::time::Duration;

    use cpal::traits::{DeviceTrait, HostTrait, StreamTrait};

    /// An open input stream.
    pub struct SoundCard {
        name: String,
        rate: u32,
        rx: mpsc::Receiver<Result<Vec<f32>, String>>,
        dropped: Arc<AtomicU64>,
        _stream: cpal::Stream,
    }

    /// Hands a block to the reader, or counts it as lost when the reader is behind.
    fn hand_over(
        tx: &mpsc::SyncSender<Result<Vec<f32>, String>>,
        dropped: &AtomicU64,
        b: Vec<f32>,
    ) {
        if tx.try_send(Ok(b)).is_err() {
            dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Input devices, by name.
    pub fn list() -> Result<Vec<String>, String> {
        let host = cpal::default_host();
        let devices = host
            .input_devices()
            .map_err(|e| format!("listing sound cards: {e}"))?;
        Ok(devices.filter_map(|d| d.name().ok()).collect())
    }

    impl SoundCard {
        /// Opens `name` (`default`: the system's default input) and starts it.
        pub fn open(name: &str) -> Result<Self, String> {
            let host = cpal::default_host();
            let device = if name == "default" {
                host.default_input_device().ok_or(
                    "no default sound card input: check `arecord -l` and your audio settings",
                )?
            } else {
                let mut found = None;
                for d in host
                    .input_devices()
                    .map_err(|e| format!("listing sound cards: {e}"))?
                {
                    if d.name().is_ok_and(|n| n == name) {
                        found = Some(d);
                        break;
                    }
                }
                found.ok_or_else(|| {
                    let names = list().unwrap_or_default();
                    format!(
                        "no sound card input named {name:?}; there are: {}",
                        if names.is_empty() {
                            "none".to_string()
                        } else {
                            names.join(", ")
                        }
                    )
                })?
            };
            let name = device.name().unwrap_or_else(|_| name.to_string());
            // 48 kHz where the card has it (every card does; no resampling in between),
            // else the card's own default.
            let usable = |f: cpal::SampleFormat| {
                matches!(
                    f,
                    cpal::SampleFormat::F32 | cpal::SampleFormat::I16 | cpal::SampleFormat::I32
                )
            };
            let at_48k = device.supported_input_configs().ok().and_then(|mut c| {
                c.find(|r| {
                    usable(r.sample_format())
                        && r.min_sample_rate().0 <= 48_000
                        && r.max_sample_rate().0 >= 48_000
                })
                .map(|r| r.with_sample_rate(cpal::SampleRate(48_000)))
            });
            let supported = match at_48k {
                Some(c) => c,
                None => device.default_input_config().map_err(|e| {
                    format!(
                        "sound card {name}: {e}; check that it is connected and free (arecord -l)"
                    )
                })?,
            };
            let channels = usize::from(supported.channels()).max(1);
            let rate = supported.sample_rate().0;
            let format = supported.sample_format();
            let config: cpal::StreamConfig = supported.into();
            let (tx, rx) = mpsc::sync_channel::<Result<Vec<f32>, String>>(64);
            let err_tx = tx.clone();
            let dropped = Arc::new(AtomicU64::new(0));
            let lost = dropped.clone();
            let err_name = name.clone();
            let on_error = move |e: cpal::StreamError| {
                let _ = err_tx.try_send(Err(format!(
                    "sound card {err_name}: {e}; the device disappeared or stopped (check that it is still connected: arecord -l)"
                )));
            };
            let stream = match format {
                cpal::SampleFormat::F32 => device.build_input_stream(
                    &config,
                    move |data: &[f32], _: &cpal::InputCallbackInfo| {
                        hand_over(&tx, &lost, data.iter().step_by(channels).copied().collect());
                    },
                    on_error,
                    None,
                ),
                cpal::SampleFormat::I16 => device.build_input_stream(
                    &config,
                    move |data: &[i16], _: &cpal::InputCallbackInfo| {
                        hand_over(
                            &tx,
                            &lost,
                            data.iter()
                                .step_by(channels)
                                .map(|&s| f32::from(s) / 32768.0)
                                .collect(),
                        );
                    },
                    on_error,
                    None,
                ),
                cpal::SampleFormat::I32 => device.build_input_stream(
                    &config,
                    move |data: &[i32], _: &cpal::InputCallbackInfo| {
                        hand_over(
                            &tx,
                            &lost,
                            data.iter()
                                .step_by(channels)
                                .map(|&s| (f64::from(s) / 2_147_483_648.0) as f32)
                                .collect(),
                        );
                    },
                    on_error,
                    None,
                ),
                other => {
                    return Err(format!(
                    "sound card {name}: sample format {other} is not supported (f32, i16, i32 are)"
                ))
                }
            }
            .map_err(|e| format!("sound card {name}: {e}"))?;
            stream
                .play()
                .map_err(|e| format!("sound card {name}: {e}"))?;
            Ok(SoundCard {
                name,
                rate,
                rx,
                dropped,
                _stream: stream,
            })
        }

        /// The card's name.
        pub fn name(&self) -> &str {
            &self.name
        }

        /// Its sample rate.
        pub fn rate(&self) -> u32 {
            self.rate
        }

        /// Blocks the card delivered while the reader was too far behind to take them.
        pub fn dropped(&self) -> u64 {
            self.dropped.load(Ordering::Relaxed)
        }

        /// The next block of samples (full scale ±1); an error when the card reports
        /// one or sends nothing for [`super::STALL_SECONDS`].
        pub fn next_block(&self) -> Result<Option<Vec<f32>>, String> {
            match self
                .rx
                .recv_timeout(Duration::from_secs(super::STALL_SECONDS))
            {
                Ok(Ok(b)) => Ok(Some(b)),
                Ok(Err(e)) => Err(e),
                Err(mpsc::RecvTimeoutError::Timeout) => Err(format!(
                    "sound card {}: no samples for {} s; the device disappeared or is used by another program",
                    self.name,
                    super::STALL_SECONDS
                )),
                Err(mpsc::RecvTimeoutError::Disconnected) => Ok(None),
            }
        }
    }
}

#[cfg(not(feature = "sound-card"))]
mod imp {
    const NOT_BUILT: &str = "this hartkit was built without sound card input: build it with \
        `cargo build --release -p hartkit --features sound-card` (on Linux install libasound2-dev \
        first), or pipe the card in: arecord -q -f S16_LE -r 48000 -c 1 -t raw | \
        hartkit modem rx --raw s16le --rate 48000 -";

    /// An open input stream (not built in).
    pub struct SoundCard {
        _never: std::convert::Infallible,
    }

    /// Input devices, by name (not built in).
    pub fn list() -> Result<Vec<String>, String> {
        Err(NOT_BUILT.into())
    }

    impl SoundCard {
        /// Says how to get sound card input.
        pub fn open(_name: &str) -> Result<Self, String> {
            Err(NOT_BUILT.into())
        }

        /// The card's name.
        pub fn name(&self) -> &str {
            match self._never {}
        }

        /// Its sample rate.
        pub fn rate(&self) -> u32 {
            match self._never {}
        }

        /// Blocks lost.
        pub fn dropped(&self) -> u64 {
            match self._never {}
        }

        /// The next block of samples.
        pub fn next_block(&self) -> Result<Option<Vec<f32>>, String> {
            match self._never {}
        }
    }
}

pub use imp::{list, SoundCard};
