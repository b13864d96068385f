//! The routes: pages, assets and the JSON API under `/api/`.

use std::collections::{BTreeMap, HashMap};
use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use axum::body::Bytes;
use axum::extract::{ConnectInfo, DefaultBodyLimit, Path, Query, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{AppendHeaders, Html, IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures::Stream;
use hart_access::WriteRecord;
use hart_poller::WriteOp;
use hart_proto::command::Empty;
use hart_proto::Request;
use serde_json::{json, Value};

use crate::auth::{self, SessionView, LOGIN_COOKIE, SESSION_COOKIE};
use crate::device::{self, Planned};
use crate::html::Visitor;
use crate::limits::LocalAddr;
use crate::pages::{self, Banner};
use crate::state::{lock, AppState, MAX_EVENT_STREAMS};
use crate::svg::{self, Series};
use crate::traffic::{self, Filter};
use crate::ApiError;

type St = State<Arc<AppState>>;
type Q = Query<HashMap<String, String>>;

/// Largest request body: writes and logins are a few hundred bytes.
pub(crate) const MAX_BODY: usize = 16 * 1024;

const STYLE: &str = include_str!("../assets/style.css");
const SCRIPT: &str = include_str!("../assets/app.js");

/// Every route of the dashboard.
pub(crate) fn router(state: Arc<AppState>) -> Router {
    Router::new()
        .route("/", get(plant_page))
        .route("/device/{id}", get(device_page))
        .route("/device/{id}/write", post(device_write_form))
        .route("/device/{id}/trend.svg", get(trend_svg))
        .route("/traffic", get(traffic_page))
        .route("/login", get(login_page).post(login_form))
        .route("/logout", post(logout_form))
        .route("/favicon.ico", get(|| async { StatusCode::NO_CONTENT }))
        .route(
            "/assets/style.css",
            get(|| asset(STYLE, "text/css; charset=utf-8")),
        )
        .route(
            "/assets/app.js",
            get(|| asset(SCRIPT, "text/javascript; charset=utf-8")),
        )
        .route("/api/devices", get(api_devices))
        .route("/api/devices/{id}", get(api_device))
        .route("/api/devices/{id}/identity", get(api_identity))
        .route("/api/devices/{id}/variables", get(api_variables))
        .route("/api/devices/{id}/status", get(api_status))
        .route("/api/devices/{id}/burst", get(api_burst))
        .route("/api/devices/{id}/history", get(api_history))
        .route("/api/devices/{id}/write", post(api_write))
        .route("/api/traffic", get(api_traffic))
        .route("/api/traffic.pcapng", get(api_pcapng))
        .route("/api/events", get(api_events))
        .route("/api/login", post(api_login))
        .route("/api/logout", post(api_logout))
        .route("/api/session", get(api_session))
        .fallback(not_found)
        .layer(DefaultBodyLimit::max(MAX_BODY))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            check_names,
        ))
        .layer(axum::middleware::from_fn(security_headers))
        .with_state(state)
}

/// The names a request was sent to: its `Host` (or HTTP/2 `:authority`, or both when
/// both are given) must be one of the dashboard's; a request that changes something
/// with an `Origin` must come from an allowed origin (crate::hosts).
async fn check_names(
    State(state): St,
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let allowed = allowed(&state, req.extensions().get::<LocalAddr>());
    let host = req
        .headers()
        .get(header::HOST)
        .map(|h| h.to_str().unwrap_or("(not text)").to_string());
    let authority = req.uri().authority().map(|a| a.as_str().to_string());
    let api = req.uri().path().starts_with("/api/");
    let names: Vec<&String> = host.iter().chain(authority.iter()).collect();
    if names.is_empty() {
        return refuse_host(api, None);
    }
    if let Some(bad) = names.iter().find(|n| !allowed.authority(n)) {
        return refuse_host(api, Some(bad));
    }
    if !req.method().is_safe() {
        if let Err(e) = same_origin(&state, req.headers(), names[0]) {
            return e.into_response();
        }
    }
    next.run(req).await
}

/// What the names of a request are checked against.
fn allowed<'a>(state: &'a AppState, local: Option<&LocalAddr>) -> crate::hosts::Allowed<'a> {
    crate::hosts::Allowed {
        names: &state.config.hosts,
        bind: state.config.bind,
        local: local.map(|l| l.0),
    }
}

/// 421 for a request to a name that is not the dashboard's, saying how to allow it.
fn refuse_host(api: bool, host: Option<&str>) -> Response {
    let message = match host {
        Some(h) => {
            let name = crate::hosts::split_authority(h)
                .map_or_else(|| h.to_string(), |(n, _)| n.to_string());
            format!(
                "this dashboard does not answer to the name {h:?}: if it is a name of this \
                 gateway, add it to the gateway's configuration ([web] hosts = [\"{name}\"], \
                 or --web-host {name}); see docs/web.md"
            )
        }
        None => "the request names no Host: give the Host header".to_string(),
    };
    if api {
        ApiError::new(StatusCode::MISDIRECTED_REQUEST, message).into_response()
    } else {
        (
            StatusCode::MISDIRECTED_REQUEST,
            [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
            format!("421 Misdirected Request: {message}\n"),
        )
            .into_response()
    }
}

/// Headers on every answer: no framing, no sniffing, scripts and styles from the
/// gateway only, no caching of pages that show live values.
async fn security_headers(req: axum::extract::Request, next: axum::middleware::Next) -> Response {
    let mut res = next.run(req).await;
    let h = res.headers_mut();
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; \
             frame-ancestors 'none'; form-action 'self'; base-uri 'none'",
        ),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("same-origin"),
    );
    h.entry(header::CACHE_CONTROL)
        .or_insert(HeaderValue::from_static("no-store"));
    res
}

async fn asset(body: &'static str, kind: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, kind),
            (header::CACHE_CONTROL, "max-age=300"),
        ],
        body,
    )
        .into_response()
}

async fn not_found(uri: axum::http::Uri, State(state): St, headers: HeaderMap) -> Response {
    if uri.path().starts_with("/api/") {
        return ApiError::not_found(format!(
            "no such API endpoint {}; docs/web.md lists them",
            uri.path()
        ))
        .into_response();
    }
    let session = session(&state, &headers);
    let visitor = visitor(&state, session.as_ref());
    (
        StatusCode::NOT_FOUND,
        Html(pages::error(
            "Not found",
            "There is no such page.",
            &visitor,
        )),
    )
        .into_response()
}

/// The session of the request's cookie, if alive.
fn session(state: &AppState, headers: &HeaderMap) -> Option<SessionView> {
    let token = auth::cookie(headers, SESSION_COOKIE)?;
    lock(&state.sessions).get(&token, Instant::now(), state.config.session_idle)
}

fn visitor<'a>(state: &AppState, session: Option<&'a SessionView>) -> Visitor<'a> {
    Visitor {
        session,
        writes: state.writes(),
    }
}

/// A request that changes something came from one of the gateway's own pages (or a
/// tool that sends no Origin): a browser's Origin must be the dashboard's name it was
/// sent to (its `Host`, one of the allowed names) or a name of `[web] hosts` given with
/// its port.
///
/// Checked for every request but GET, HEAD, OPTIONS and TRACE, before its handler.
fn same_origin(state: &AppState, headers: &HeaderMap, host: &str) -> Result<(), ApiError> {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return Ok(());
    };
    let origin = origin.to_str().unwrap_or("(not text)");
    if allowed(state, None).origin(origin, host) {
        Ok(())
    } else {
        Err(ApiError::forbidden(format!(
            "cross-site request refused (Origin {origin}, Host {host}): a change must come \
             from the dashboard's own pages; behind a proxy, give its name with its port in \
             [web] hosts"
        )))
    }
}

/// The session a write needs, with its CSRF token checked.
fn authorize_write(
    state: &AppState,
    headers: &HeaderMap,
    csrf: Option<&str>,
) -> Result<SessionView, ApiError> {
    if state.read_only() {
        return Err(ApiError::forbidden(format!(
            "{}: no writes",
            hart_poller::NotPermitted::ReadOnly
        )));
    }
    if !state.writes() {
        return Err(ApiError::forbidden(
            "writes are off: start the gateway with --web-admin-password-file FILE",
        ));
    }
    let Some(s) = session(state, headers) else {
        return Err(ApiError::new(
            StatusCode::UNAUTHORIZED,
            "log in first: POST /api/login with the administrator's password, or the Log in page",
        ));
    };
    if !csrf.is_some_and(|c| auth::token_matches(c, &s.csrf)) {
        return Err(ApiError::forbidden(
            "the CSRF token is missing or wrong: reload the page (API: send the csrf value \
             /api/login gave in the X-CSRF-Token header)",
        ));
    }
    Ok(s)
}

// --- pages -------------------------------------------------------------------------

async fn plant_page(State(state): St, headers: HeaderMap) -> Html<String> {
    let s = session(&state, &headers);
    Html(pages::plant(&state, &visitor(&state, s.as_ref())))
}

/// The device of a page's path, or the page that says there is none.
fn resolve_page(state: &AppState, id: &str, v: &Visitor<'_>) -> Result<usize, Box<Response>> {
    device::resolve(&state.engine, id).map_err(|e| {
        (
            e.status,
            Html(pages::error("No such device", &e.message, v)),
        )
            .into_response()
            .into()
    })
}

async fn device_page(
    State(state): St,
    Path(id): Path<String>,
    Query(q): Q,
    headers: HeaderMap,
) -> Response {
    let s = session(&state, &headers);
    let v = visitor(&state, s.as_ref());
    let position = match resolve_page(&state, &id, &v) {
        Ok(p) => p,
        Err(page) => return *page,
    };
    let window = q
        .get("window")
        .filter(|w| crate::trend::parse_window(w).is_ok())
        .cloned()
        .unwrap_or_else(|| "1h".into());
    Html(pages::device(&state, position, &v, None, &window).await).into_response()
}

async fn traffic_page(State(state): St, headers: HeaderMap) -> Html<String> {
    let s = session(&state, &headers);
    Html(pages::traffic(&state, &visitor(&state, s.as_ref())))
}

/// A form's `a=1&b=2` as fields (the last of a name repeated wins).
fn form_fields(body: &[u8]) -> Result<BTreeMap<String, String>, ApiError> {
    let pairs: Vec<(String, String)> = serde_urlencoded::from_bytes(body)
        .map_err(|e| ApiError::bad_request(format!("the form could not be read: {e}")))?;
    Ok(pairs.into_iter().collect())
}

async fn device_write_form(
    State(state): St,
    Path(id): Path<String>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: Result<Bytes, axum::extract::rejection::BytesRejection>,
) -> Response {
    let s = session(&state, &headers);
    let v = visitor(&state, s.as_ref());
    let position = match resolve_page(&state, &id, &v) {
        Ok(p) => p,
        Err(page) => return *page,
    };
    let outcome = async {
        let body = body.map_err(|e| ApiError::new(e.status(), e.body_text()))?;
        let mut fields = form_fields(&body)?;
        let csrf = fields.remove("csrf");
        let session = authorize_write(&state, &headers, csrf.as_deref())?;
        let planned = device::plan(&fields)?;
        write(&state, position, planned, peer, &session).await
    }
    .await;
    let (status, banner) = match outcome {
        Ok(v) => (
            StatusCode::OK,
            Banner {
                ok: v["confirmed"].as_bool() == Some(true),
                text: v["message"].as_str().unwrap_or("").to_string(),
            },
        ),
        Err(e) => (
            e.status,
            Banner {
                ok: false,
                text: e.message,
            },
        ),
    };
    (
        status,
        Html(pages::device(&state, position, &v, Some(banner), "1h").await),
    )
        .into_response()
}

async fn login_page(State(state): St, headers: HeaderMap) -> Response {
    let token = auth::cookie(&headers, LOGIN_COOKIE)
        .filter(|t| t.len() == 64)
        .or_else(auth::random_token);
    let Some(token) = token else {
        return ApiError::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "no random numbers from the system",
        )
        .into_response();
    };
    let writes = state.writes();
    (
        [(
            header::SET_COOKIE,
            auth::set_cookie(LOGIN_COOKIE, &token, state.secure, None),
        )],
        Html(pages::login(
            &token,
            None,
            writes,
            !state.config.psk_logins.is_empty(),
        )),
    )
        .into_response()
}

/// Checks a login; on success, the `Set-Cookie` values (the session's, the trusted
/// browser's) and the session.
fn log_in(
    state: &AppState,
    peer: SocketAddr,
    headers: &HeaderMap,
    identity: Option<&str>,
    password: Option<&str>,
) -> Result<(Vec<String>, SessionView), ApiError> {
    if !state.writes() {
        return Err(ApiError::forbidden(
            "writes are off on this gateway (no --web-admin-password-file, no PSK identity \
             with write rights): there is nothing to log in to",
        ));
    }
    let identity = identity.map(str::trim).filter(|i| !i.is_empty());
    let browser = auth::cookie(headers, auth::TRUSTED_COOKIE);
    let browser = browser.as_deref();
    let now = Instant::now();
    let mut sessions = lock(&state.sessions);
    match sessions.refused_for(peer.ip(), browser, now) {
        None => {}
        Some(auth::Throttled::Address(wait)) => {
            let s = wait.as_secs() + 1;
            return Err(ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "too many failed logins from {}: try again in {s} s",
                    peer.ip()
                ),
            )
            .retry_after(s));
        }
        Some(auth::Throttled::Everyone(wait)) => {
            let s = wait.as_secs() + 1;
            return Err(ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "too many failed logins to this gateway in the last minute, from \
                     several addresses (password guessing?): logins from browsers that \
                     have not logged in here before wait; try again in {s} s"
                ),
            )
            .retry_after(s));
        }
    }
    // An identity logs in with its pre-shared key; no identity, the administrator with
    // the password.
    let who = match identity {
        Some(id) => state
            .config
            .psk_logins
            .iter()
            .find(|l| l.identity == id)
            .filter(|l| password.is_some_and(|p| auth::key_matches(p, &l.key)))
            .map(|l| l.identity.clone()),
        None => state
            .password
            .as_deref()
            .filter(|expected| password.is_some_and(|p| auth::password_matches(p, expected)))
            .map(|_| "administrator".to_string()),
    };
    let Some(who) = who else {
        sessions.failed(peer.ip(), browser, now);
        tracing::warn!("web: a failed login from {peer}");
        return Err(ApiError::new(
            StatusCode::UNAUTHORIZED,
            if identity.is_some() {
                "unknown identity, an identity without write rights, or a wrong key"
            } else {
                "wrong password"
            },
        ));
    };
    let trusted = sessions.succeeded(peer.ip(), browser, now);
    let (token, view) = sessions.create(now, &who).ok_or_else(|| {
        ApiError::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "no random numbers from the system",
        )
    })?;
    tracing::info!("web: {who} logged in from {peer} (session {})", view.number);
    let mut cookies = vec![auth::set_cookie(SESSION_COOKIE, &token, state.secure, None)];
    if let Some(t) = trusted {
        cookies.push(auth::set_cookie(
            auth::TRUSTED_COOKIE,
            &t,
            state.secure,
            Some(auth::TRUSTED_LIFE.as_secs()),
        ));
    }
    Ok((cookies, view))
}

async fn login_form(
    State(state): St,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: Result<Bytes, axum::extract::rejection::BytesRejection>,
) -> Response {
    let writes = state.writes();
    let outcome = async {
        let body = body.map_err(|e| ApiError::new(e.status(), e.body_text()))?;
        let fields = form_fields(&body)?;
        let cookie = auth::cookie(&headers, LOGIN_COOKIE).unwrap_or_default();
        if !fields
            .get("csrf")
            .is_some_and(|c| auth::token_matches(c, &cookie))
        {
            return Err(ApiError::forbidden(
                "the login form's token is missing or wrong: open the login page again",
            ));
        }
        log_in(
            &state,
            peer,
            &headers,
            fields.get("identity").map(String::as_str),
            fields.get("password").map(String::as_str),
        )
    }
    .await;
    match outcome {
        Ok((cookies, _)) => (
            AppendHeaders(
                cookies
                    .into_iter()
                    .chain([auth::set_cookie(LOGIN_COOKIE, "", state.secure, Some(0))])
                    .map(|c| (header::SET_COOKIE, c)),
            ),
            Redirect::to("/"),
        )
            .into_response(),
        Err(e) => {
            let token = auth::cookie(&headers, LOGIN_COOKIE)
                .filter(|t| t.len() == 64)
                .or_else(auth::random_token)
                .unwrap_or_default();
            let mut res = (
                e.status,
                [(
                    header::SET_COOKIE,
                    auth::set_cookie(LOGIN_COOKIE, &token, state.secure, None),
                )],
                Html(pages::login(
                    &token,
                    Some(&e.message),
                    writes,
                    !state.config.psk_logins.is_empty(),
                )),
            )
                .into_response();
            if let Some(s) = e.retry_after {
                res.headers_mut().insert(header::RETRY_AFTER, s.into());
            }
            res
        }
    }
}

fn end_session(state: &AppState, headers: &HeaderMap) -> String {
    if let Some(t) = auth::cookie(headers, SESSION_COOKIE) {
        lock(&state.sessions).remove(&t);
    }
    auth::set_cookie(SESSION_COOKIE, "", state.secure, Some(0))
}

async fn logout_form(
    State(state): St,
    headers: HeaderMap,
    body: Result<Bytes, axum::extract::rejection::BytesRejection>,
) -> Response {
    let fields = body
        .ok()
        .and_then(|b| form_fields(&b).ok())
        .unwrap_or_default();
    let ok = session(&state, &headers).is_some_and(|s| {
        fields
            .get("csrf")
            .is_some_and(|c| auth::token_matches(c, &s.csrf))
    });
    if !ok {
        return ApiError::forbidden("log out from the gateway's own page").into_response();
    }
    (
        [(header::SET_COOKIE, end_session(&state, &headers))],
        Redirect::to("/"),
    )
        .into_response()
}

// --- writes ------------------------------------------------------------------------

/// Carries out a planned write for `session` from `peer`, reads it back, and arranges
/// a loop test's automatic release.
async fn write(
    state: &Arc<AppState>,
    position: usize,
    planned: Planned,
    peer: SocketAddr,
    session: &SessionView,
) -> Result<Value, ApiError> {
    let op = planned.op;
    let origin = WriteRecord {
        front_end: "web",
        session: Some(session.number),
        peer: peer.to_string(),
        identity: Some(session.who.clone()),
        via: "web dashboard".into(),
        ..Default::default()
    };
    // A loop test is a lease the engine holds: released after `release_after_s`
    // (capped by the gateway's limit), when the gateway stops, or by a new test.
    let lease = hart_poller::LeaseTerms {
        limit: planned.release_after,
        holder: None,
        by: format!("web session {} ({})", session.number, session.who),
    };
    let applied = state
        .engine
        .apply_with(position, &op, &origin, lease)
        .await
        .map_err(|e| device::write_error(&e))?;
    let (read_back, confirmed) = device::read_back(&state.engine, position, &op).await;
    let mut message = format!(
        "{}: {}",
        op.describe(),
        if confirmed {
            "done, read back"
        } else {
            "sent, but the read-back does not show it"
        }
    );
    if applied.response_code != 0 {
        message.push_str(&format!(
            " (warning: response code {}, {})",
            applied.response_code,
            hart_proto::tables::response_code_name(op.command(), applied.response_code)
                .unwrap_or("")
        ));
    }
    let mut out = json!({
        "ok": true,
        "operation": op.describe(),
        "command": op.command(),
        "response_code": applied.response_code,
        "response_code_name": hart_proto::tables::response_code_name(op.command(), applied.response_code),
        "confirmed": confirmed,
        "read_back": read_back,
    });
    if let WriteOp::FixedCurrent(ma) = op {
        if ma != 0.0 {
            if let Some(test) = state
                .engine
                .image()
                .with(position, |d| d.loop_test.clone())
                .flatten()
            {
                out["release_at"] =
                    json!(humantime::format_rfc3339_seconds(test.release_at).to_string());
                let left = test
                    .release_at
                    .duration_since(state.engine.clock().wall())
                    .unwrap_or_default();
                message.push_str(&format!(
                    "; released automatically in {} s",
                    left.as_secs_f64().round()
                ));
            }
        }
    }
    out["message"] = json!(message);
    Ok(out)
}

// --- API ---------------------------------------------------------------------------

async fn api_devices(State(state): St) -> Json<Value> {
    Json(state.plant_json())
}

async fn api_device(State(state): St, Path(id): Path<String>) -> Result<Json<Value>, ApiError> {
    let p = device::resolve(&state.engine, &id)?;
    state
        .engine
        .image()
        .with(p, |d| Json(device::device_json(d, &state.engine)))
        .ok_or_else(|| ApiError::not_found("no such device"))
}

async fn api_identity(State(state): St, Path(id): Path<String>) -> Result<Json<Value>, ApiError> {
    let p = device::resolve(&state.engine, &id)?;
    let zero = device::read(&state.engine, p, &Request::ReadUniqueIdentifier(Empty {})).await?;
    let long_tag = device::read(&state.engine, p, &Request::ReadLongTag(Empty {}))
        .await
        .ok();
    Ok(Json(json!({"command_0": zero, "command_20": long_tag})))
}

async fn api_variables(State(state): St, Path(id): Path<String>) -> Result<Json<Value>, ApiError> {
    let p = device::resolve(&state.engine, &id)?;
    let request = device::variables_request(&state.engine, p);
    device::read(&state.engine, p, &request).await.map(Json)
}

async fn api_status(State(state): St, Path(id): Path<String>) -> Result<Json<Value>, ApiError> {
    let p = device::resolve(&state.engine, &id)?;
    let request = Request::ReadAdditionalStatus(Default::default());
    device::read(&state.engine, p, &request).await.map(Json)
}

async fn api_burst(
    State(state): St,
    Path(id): Path<String>,
    Query(q): Q,
) -> Result<Json<Value>, ApiError> {
    let p = device::resolve(&state.engine, &id)?;
    let message = match q.get("message") {
        Some(m) => m
            .parse::<u8>()
            .map_err(|_| ApiError::bad_request("message: give a burst message number 0-255"))?,
        None => 0,
    };
    let request = device::burst_request(&state.engine, p, message);
    device::read(&state.engine, p, &request).await.map(Json)
}

/// The PV and loop current of device `position` over `window` up to now: from the
/// historian when one runs (falling back to memory if it cannot be read), from
/// memory otherwise.
async fn history(state: &AppState, position: usize, window: Duration) -> Value {
    let to = state.engine.clock().wall();
    let from = to - window;
    let uid = state
        .engine
        .image()
        .with(position, |d| d.unique_id().map(|u| u.to_string()))
        .flatten();
    let mut error = None;
    if let (Some(readers), Some(uid)) = (state.config.history.clone(), uid) {
        let every = (window / 300).max(Duration::from_secs(1));
        let q = move |var| hart_history::Query {
            device: uid.clone(),
            var,
            from,
            to,
            every: Some(every),
            agg: hart_history::Agg::Mean,
        };
        let (qp, qc) = (q(hart_history::Var::Pv), q(hart_history::Var::LoopCurrent));
        let read = tokio::task::spawn_blocking(move || {
            readers.read(|store| Ok((store.query(&qp)?, store.query(&qc)?)))
        })
        .await;
        match read {
            Ok(Ok((pv, current))) => {
                let units = pv.iter().rev().find_map(|p| p.units);
                let mut points: BTreeMap<SystemTime, (Option<f64>, Option<f64>)> = BTreeMap::new();
                for p in &pv {
                    points.entry(p.time).or_default().0 = p.value.filter(|_| p.quality == 0);
                }
                for p in &current {
                    points.entry(p.time).or_default().1 = p.value.filter(|_| p.quality == 0);
                }
                return history_json(
                    "historian",
                    from,
                    to,
                    units,
                    points.into_iter().map(|(t, (a, b))| (t, a, b)),
                );
            }
            Ok(Err(e)) => error = Some(e.to_string()),
            Err(e) => error = Some(e.to_string()),
        }
    }
    let (points, units) = {
        let trend = lock(&state.trend);
        (trend.since(position, from), trend.units(position))
    };
    let mut v = history_json(
        "memory",
        from,
        to,
        units,
        points.into_iter().map(|p| (p.time, p.pv, p.current)),
    );
    if let Some(e) = error {
        v["history_error"] = json!(e);
    }
    v
}

fn history_json(
    source: &str,
    from: SystemTime,
    to: SystemTime,
    units: Option<u8>,
    points: impl Iterator<Item = (SystemTime, Option<f64>, Option<f64>)>,
) -> Value {
    let t = |t: SystemTime| humantime::format_rfc3339_millis(t).to_string();
    let points: Vec<Value> = points
        .map(|(time, pv, current)| json!({"time": t(time), "pv": pv, "loop_current": current}))
        .collect();
    json!({
        "source": source,
        "from": t(from),
        "to": t(to),
        "pv_units": units,
        "pv_units_symbol": units.and_then(hart_proto::tables::unit_symbol),
        "points": points,
    })
}

fn window_of(q: &HashMap<String, String>) -> Result<Duration, ApiError> {
    q.get("window")
        .map_or(Ok(Duration::from_secs(3600)), |w| {
            crate::trend::parse_window(w)
        })
        .map_err(ApiError::bad_request)
}

async fn api_history(
    State(state): St,
    Path(id): Path<String>,
    Query(q): Q,
) -> Result<Json<Value>, ApiError> {
    let p = device::resolve(&state.engine, &id)?;
    let window = window_of(&q)?;
    Ok(Json(history(&state, p, window).await))
}

async fn trend_svg(State(state): St, Path(id): Path<String>, Query(q): Q) -> Response {
    let p = match device::resolve(&state.engine, &id) {
        Ok(p) => p,
        Err(e) => return e.into_response(),
    };
    let window = match window_of(&q) {
        Ok(w) => w,
        Err(e) => return e.into_response(),
    };
    let h = history(&state, p, window).await;
    let name = state
        .engine
        .image()
        .with(p, |d| d.display_name())
        .unwrap_or_default();
    let from = h["from"]
        .as_str()
        .and_then(|s| humantime::parse_rfc3339(s).ok())
        .unwrap_or_else(|| state.engine.clock().wall());
    let secs = |p: &Value| {
        p["time"]
            .as_str()
            .and_then(|s| humantime::parse_rfc3339(s).ok())
            .and_then(|t| t.duration_since(from).ok())
            .map_or(0.0, |d| d.as_secs_f64())
    };
    let pts = h["points"].as_array().cloned().unwrap_or_default();
    let pv = Series {
        name: "PV".into(),
        units: h["pv_units"].as_str().unwrap_or("").to_string(),
        color: "#1f6fb4",
        points: pts.iter().map(|p| (secs(p), p["pv"].as_f64())).collect(),
    };
    let current = Series {
        name: "Loop current".into(),
        units: "mA".into(),
        color: "#d0641c",
        points: pts
            .iter()
            .map(|p| (secs(p), p["loop_current"].as_f64()))
            .collect(),
    };
    let title = format!(
        "{name}: last {} ({})",
        humantime::format_duration(window),
        h["source"].as_str().unwrap_or("")
    );
    (
        [(header::CONTENT_TYPE, "image/svg+xml")],
        svg::chart(&title, window.as_secs_f64(), &pv, Some(&current)),
    )
        .into_response()
}

/// A JSON body (`Content-Type: application/json`), as fields.
fn json_fields(
    headers: &HeaderMap,
    body: Result<Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<BTreeMap<String, String>, ApiError> {
    let body = body.map_err(|e| ApiError::new(e.status(), e.body_text()))?;
    let kind = headers
        .get(header::CONTENT_TYPE)
        .and_then(|c| c.to_str().ok())
        .unwrap_or("");
    if !kind.starts_with("application/json") {
        return Err(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "send the body as JSON with Content-Type: application/json",
        ));
    }
    let v: Value = serde_json::from_slice(&body)
        .map_err(|e| ApiError::bad_request(format!("the body is not JSON: {e}")))?;
    device::fields_of_json(&v)
}

async fn api_write(
    State(state): St,
    Path(id): Path<String>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: Result<Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<Json<Value>, ApiError> {
    let p = device::resolve(&state.engine, &id)?;
    let mut fields = json_fields(&headers, body)?;
    let csrf = headers
        .get("x-csrf-token")
        .and_then(|v| v.to_str().ok())
        .map(str::to_string)
        .or_else(|| fields.get("csrf").cloned());
    fields.remove("csrf");
    let session = authorize_write(&state, &headers, csrf.as_deref())?;
    let planned = device::plan(&fields)?;
    write(&state, p, planned, peer, &session).await.map(Json)
}

async fn api_login(
    State(state): St,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: Result<Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<Response, ApiError> {
    let fields = json_fields(&headers, body)?;
    let (cookies, view) = log_in(
        &state,
        peer,
        &headers,
        fields.get("identity").map(String::as_str),
        fields.get("password").map(String::as_str),
    )?;
    Ok((
        AppendHeaders(cookies.into_iter().map(|c| (header::SET_COOKIE, c))),
        Json(
            json!({"logged_in": true, "csrf": view.csrf, "session": view.number, "who": view.who}),
        ),
    )
        .into_response())
}

async fn api_logout(State(state): St, headers: HeaderMap) -> Result<Response, ApiError> {
    let Some(s) = session(&state, &headers) else {
        return Err(ApiError::new(StatusCode::UNAUTHORIZED, "not logged in"));
    };
    let given = headers.get("x-csrf-token").and_then(|v| v.to_str().ok());
    if !given.is_some_and(|c| auth::token_matches(c, &s.csrf)) {
        return Err(ApiError::forbidden(
            "the X-CSRF-Token header is missing or wrong",
        ));
    }
    Ok((
        [(header::SET_COOKIE, end_session(&state, &headers))],
        Json(json!({"logged_in": false})),
    )
        .into_response())
}

async fn api_session(State(state): St, headers: HeaderMap) -> Json<Value> {
    let s = session(&state, &headers);
    Json(json!({
        "logged_in": s.is_some(),
        "writes": state.writes(),
        "csrf": s.map(|s| s.csrf),
    }))
}

/// The traffic filter of a query: `loop`, `device`, `command`, `after`.
fn filter_of(state: &AppState, q: &HashMap<String, String>) -> Result<Filter, ApiError> {
    let given = |k: &str| q.get(k).map(|s| s.trim()).filter(|s| !s.is_empty());
    let mut f = Filter::default();
    if let Some(l) = given("loop") {
        let c = l
            .parse::<u8>()
            .ok()
            .filter(|c| usize::from(*c) < state.engine.loop_count())
            .or_else(|| {
                (0..state.engine.loop_count())
                    .find(|&c| state.engine.loop_name(c) == Some(l))
                    .and_then(|c| u8::try_from(c).ok())
            })
            .ok_or_else(|| ApiError::bad_request(format!("loop {l:?}: no such loop")))?;
        f.channel = Some(c);
    }
    if let Some(d) = given("device") {
        let p = device::resolve(&state.engine, d)?;
        f.device = state
            .engine
            .image()
            .with(p, |d| (d.channel, d.unique_id(), d.polling_address));
    }
    if let Some(c) = given("command") {
        f.command = Some(c.parse::<u16>().map_err(|_| {
            ApiError::bad_request(format!("command {c:?}: give a command number 0-65535"))
        })?);
    }
    if let Some(a) = given("after") {
        f.after = Some(
            a.parse::<u64>()
                .map_err(|_| ApiError::bad_request(format!("after {a:?}: give a frame number")))?,
        );
    }
    Ok(f)
}

fn limit_of(q: &HashMap<String, String>, default: usize) -> Result<usize, ApiError> {
    q.get("limit").map_or(Ok(default), |l| {
        l.parse::<usize>()
            .ok()
            .filter(|l| (1..=crate::state::TRAFFIC_KEPT).contains(l))
            .ok_or_else(|| {
                ApiError::bad_request(format!(
                    "limit {l:?}: give 1 to {}",
                    crate::state::TRAFFIC_KEPT
                ))
            })
    })
}

fn loop_name(state: &AppState, channel: u8) -> String {
    state
        .engine
        .loop_name(usize::from(channel))
        .unwrap_or("?")
        .to_string()
}

async fn api_traffic(State(state): St, Query(q): Q) -> Result<Json<Value>, ApiError> {
    let filter = filter_of(&state, &q)?;
    let limit = limit_of(&q, 200)?;
    let (frames, last, lost) = {
        let log = lock(&state.traffic);
        (log.select(&filter, limit), log.last_seq(), log.lost_count())
    };
    let frames: Vec<Value> = frames
        .iter()
        .map(|(seq, f)| traffic::frame_json(*seq, f, &loop_name(&state, f.channel)))
        .collect();
    Ok(Json(
        json!({"last_seq": last, "lost": lost, "frames": frames}),
    ))
}

async fn api_pcapng(State(state): St, Query(q): Q) -> Result<Response, ApiError> {
    let filter = filter_of(&state, &q)?;
    let limit = limit_of(&q, crate::state::TRAFFIC_KEPT)?;
    let frames = lock(&state.traffic).select(&filter, limit);
    let bytes = traffic::pcapng(&frames, |c| loop_name(&state, c))
        .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, e))?;
    Ok((
        [
            (header::CONTENT_TYPE, "application/x-pcapng"),
            (
                header::CONTENT_DISPOSITION,
                "attachment; filename=\"hartkit-traffic.pcapng\"",
            ),
        ],
        bytes,
    )
        .into_response())
}

/// Counts an open event stream; the count goes down when the stream is dropped.
struct StreamSlot(Arc<AppState>);

impl Drop for StreamSlot {
    fn drop(&mut self) {
        self.0
            .streams
            .fetch_sub(1, std::sync::atomic::Ordering::Relaxed);
    }
}

/// The plant view's live values: a `plant` event with the whole plant at once, then
/// one at each change (at most two a second) and every two seconds.
async fn api_events(
    State(state): St,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    use std::sync::atomic::Ordering;
    if state.streams.fetch_add(1, Ordering::Relaxed) >= MAX_EVENT_STREAMS {
        state.streams.fetch_sub(1, Ordering::Relaxed);
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("{MAX_EVENT_STREAMS} live views are open already; close some"),
        ));
    }
    let slot = StreamSlot(state.clone());
    let first: Arc<str> = state.plant_json().to_string().into();
    let rx = state.events.subscribe();
    let updates = futures::stream::unfold((rx, slot), |(mut rx, slot)| async move {
        loop {
            match rx.recv().await {
                Ok(text) => return Some((text, (rx, slot))),
                // Behind: the next snapshot is whole anyway.
                Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => continue,
                Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
            }
        }
    });
    let stream = futures::StreamExt::map(
        futures::StreamExt::chain(futures::stream::once(async move { first }), updates),
        |text: Arc<str>| Ok(Event::default().event("plant").data(&*text)),
    );
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}
