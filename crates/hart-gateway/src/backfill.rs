//! The MQTT publisher's store-and-forward, backed by the historian: when its backlog in
//! memory is full, the rest of an outage is read back from the historian (which keeps
//! every value whatever happens to the broker) and sent as historical data.

use std::collections::BTreeMap;

use hart_history::{Agg, Query, Readers, Var};
use hart_poller::{Engine, Quality};
use hart_sparkplug_edge::metrics::{Value, DEVICE_METRICS};
use hart_sparkplug_edge::Sample;

/// The historian as the source of an outage's samples.
pub struct HistoryBackfill {
    readers: Readers,
    engine: Engine,
}

impl std::fmt::Debug for HistoryBackfill {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HistoryBackfill")
            .field("readers", &self.readers)
            .finish_non_exhaustive()
    }
}

impl HistoryBackfill {
    /// Reads from the historian (the gateway's `--history`, through the handle its
    /// readers share) for the devices of `engine`.
    pub fn new(readers: Readers, engine: Engine) -> Self {
        HistoryBackfill { readers, engine }
    }
}

/// The metric of each stored variable (hart-sparkplug's one table,
/// [`hart_sparkplug_edge::metrics::STORED`]).
fn metric_of(var: Var) -> Option<usize> {
    hart_sparkplug_edge::metrics::stored_metric(var.code())
}

impl hart_sparkplug_edge::Backfill for HistoryBackfill {
    fn samples(&self, from: u64, to: u64) -> Result<Vec<Sample>, String> {
        self.readers
            .read(|store| self.samples_from(store, from, to))
            .map_err(|e| e.to_string())
    }
}

impl HistoryBackfill {
    /// [`hart_sparkplug_edge::Backfill::samples`] with a connection of the pool.
    fn samples_from(
        &self,
        store: &mut hart_history::Store,
        from: u64,
        to: u64,
    ) -> Result<Vec<Sample>, hart_history::Error> {
        let (from_t, to_t) = (
            hart_clock::epoch::from_millis(from),
            hart_clock::epoch::from_millis(to),
        );
        let quality = DEVICE_METRICS
            .iter()
            .position(|m| m.name == "Status/Quality");
        let quality_code = DEVICE_METRICS
            .iter()
            .position(|m| m.name == "Status/QualityCode");
        let mut out = vec![];
        for d in self.engine.image().snapshot() {
            let Some(id) = d.unique_id() else { continue };
            // One sample per stored time, with every variable stored at that time.
            let mut by_time: BTreeMap<u64, Vec<(usize, Value)>> = BTreeMap::new();
            for var in Var::ALL {
                let Some(metric) = metric_of(var) else {
                    continue;
                };
                let q = Query {
                    device: id.to_string(),
                    var,
                    from: from_t,
                    to: to_t,
                    every: None,
                    agg: Agg::Last,
                };
                let points = match store.query(&q) {
                    Ok(p) => p,
                    // A device the historian has not stored (yet): nothing to send.
                    Err(hart_history::Error::NoSuchDevice(_)) => break,
                    Err(e) => return Err(e),
                };
                for p in points {
                    let value = match (var, p.value) {
                        (_, None) => Value::Null,
                        (Var::DeviceStatus, Some(v)) => Value::UInt(v as u32),
                        (_, Some(v)) => Value::Float(v as f32),
                    };
                    let metrics = by_time
                        .entry(hart_clock::epoch::millis(p.time))
                        .or_default();
                    metrics.push((metric, value));
                    if var == Var::Pv {
                        let q = Quality::from_code(u16::from(p.quality));
                        if let (Some(i), Some(q)) = (quality, q) {
                            metrics.push((i, Value::Text(q.name().to_string())));
                        }
                        if let Some(i) = quality_code {
                            metrics.push((i, Value::UInt(u32::from(p.quality))));
                        }
                    }
                }
            }
            out.extend(by_time.into_iter().map(|(at, metrics)| Sample {
                position: d.position,
                at,
                metrics,
            }));
        }
        Ok(out)
    }
}
