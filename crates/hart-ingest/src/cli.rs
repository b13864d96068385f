//! The library side of `hartkit history ingest`: the command line only parses its
//! options into [`IngestArgs`].

use crate::{IngestConfig, Summary};

/// Options of `hartkit history ingest`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IngestArgs {
    /// `--mqtt URL`: the broker or the cluster's nodes.
    pub mqtt: String,
    /// `--group G`.
    pub group: String,
    /// `--history DB`: an SQLite file or a `postgres://` URL.
    pub history: String,
    /// `--client-id ID`.
    pub client_id: Option<String>,
    /// `--username NAME`.
    pub username: Option<String>,
    /// `--password-file FILE`.
    pub password_file: Option<std::path::PathBuf>,
    /// `--ca-file FILE`.
    pub ca_file: Option<std::path::PathBuf>,
}

/// Runs the ingest until Ctrl-C (SIGINT) or SIGTERM; the summary line, or the error
/// with its exit code.
pub fn ingest_command(a: &IngestArgs) -> Result<String, (String, u8)> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| (format!("cannot start the runtime: {e}"), 5))?;
    let config = IngestConfig {
        url: a.mqtt.clone(),
        group: a.group.clone(),
        db: a.history.clone(),
        client_id: a.client_id.clone(),
        writer: hart_history::WriterConfig::default(),
        username: a.username.clone(),
        password_file: a.password_file.clone(),
        ca_file: a.ca_file.clone(),
    };
    let summary: Summary = rt
        .block_on(async move {
            let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
            tokio::spawn(async move {
                stop_signal().await;
                tracing::info!("ingest: stopping: committing what was taken");
                let _ = stop_tx.send(true);
            });
            crate::run(config, stop_rx).await
        })
        .map_err(|e| (format!("history ingest: {e}"), e.exit_code()))?;
    Ok(summary.to_string())
}

async fn stop_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        if let Ok(mut term) = signal(SignalKind::terminate()) {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            return;
        }
    }
    let _ = tokio::signal::ctrl_c().await;
}
