//! Logins, sessions and CSRF tokens.
//!
//! The administrator's password comes from a file (its first line). A login makes a
//! session: a random token in a cookie (HttpOnly, SameSite=Strict, Secure over HTTPS)
//! and a random CSRF token that every form and API write must carry.
//!
//! Password guessing is throttled twice:
//!
//! * per address: after [`MAX_FAILURES`] failed logins within [`FAILURE_WINDOW`], that
//!   address's logins are refused (429) until the window passes;
//! * across addresses (an attacker with many addresses): when [`GLOBAL_MAX_FAILURES`]
//!   logins failed within the last [`FAILURE_WINDOW`], wherever from, logins are
//!   refused (429, `Retry-After`) until the oldest of them leaves the window: guessing
//!   gets at most that many tries a minute, however many addresses it has. A browser
//!   that has logged in here before (its [`TRUSTED_COOKIE`], given at each good login,
//!   random and kept by the server) is exempt, so that an attack does not lock the
//!   operators out; a cookie loses that after [`MAX_FAILURES`] failures of its own.

use std::collections::{HashMap, VecDeque};
use std::net::IpAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use axum::http::HeaderMap;
use subtle::ConstantTimeEq;

use crate::Error;

/// The session cookie's name.
pub(crate) const SESSION_COOKIE: &str = "hartkit_session";
/// The login form's CSRF cookie (double submit: there is no session yet).
pub(crate) const LOGIN_COOKIE: &str = "hartkit_login";
/// Sessions kept at most; the least recently used goes first.
const MAX_SESSIONS: usize = 64;
/// The cookie of a browser that has logged in here, exempt from the throttle across
/// addresses.
pub(crate) const TRUSTED_COOKIE: &str = "hartkit_browser";
/// Failed logins from one address within [`FAILURE_WINDOW`] before it is refused.
pub const MAX_FAILURES: u32 = 5;
/// The window of the login throttles.
pub const FAILURE_WINDOW: Duration = Duration::from_secs(60);
/// Failed logins from all addresses within [`FAILURE_WINDOW`] before logins from
/// browsers not trusted are refused.
pub const GLOBAL_MAX_FAILURES: usize = 20;
/// Browsers remembered as having logged in, at most (the oldest goes first).
const MAX_TRUSTED: usize = 256;
/// How long a browser stays trusted after its last good login.
pub const TRUSTED_LIFE: Duration = Duration::from_secs(30 * 86_400);
/// A session lasts at most this long, however used.
const SESSION_LIFE: Duration = Duration::from_secs(12 * 3600);

/// Reads the administrator's password: the file's first line, without its line end.
pub(crate) fn read_password_file(p: &Path) -> Result<String, Error> {
    let text = std::fs::read_to_string(p).map_err(|e| {
        Error::Io(format!(
            "--web-admin-password-file {}: {e}; give a file whose first line is the \
             administrator's password",
            p.display()
        ))
    })?;
    let first = text.lines().next().unwrap_or("").trim_end_matches('\r');
    if first.is_empty() {
        return Err(Error::Config(format!(
            "--web-admin-password-file {}: the first line is empty; write the password on it",
            p.display()
        )));
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        if let Ok(m) = std::fs::metadata(p) {
            if m.permissions().mode() & 0o044 != 0 {
                tracing::warn!(
                    "web: the password file {} can be read by other users; chmod 600 it",
                    p.display()
                );
            }
        }
    }
    Ok(first.to_string())
}

/// Whether `given` is the password, in time that does not depend on where they differ.
pub(crate) fn password_matches(given: &str, expected: &str) -> bool {
    given.as_bytes().ct_eq(expected.as_bytes()).into()
}

/// Whether `given` (hex, any case, spaces allowed) is `key`, in constant time.
pub(crate) fn key_matches(given: &str, key: &[u8]) -> bool {
    let hex: String = given.chars().filter(|c| !c.is_whitespace()).collect();
    if hex.len() != key.len() * 2 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return false;
    }
    let bytes: Vec<u8> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap_or(0))
        .collect();
    bytes.ct_eq(key).into()
}

/// Whether two tokens are equal, in constant time.
pub(crate) fn token_matches(given: &str, expected: &str) -> bool {
    !expected.is_empty() && given.as_bytes().ct_eq(expected.as_bytes()).into()
}

/// 32 random bytes from the operating system, as hex; `None` if it has none to give
/// (then no token is handed out).
pub(crate) fn random_token() -> Option<String> {
    let mut b = [0u8; 32];
    getrandom::getrandom(&mut b).ok()?;
    Some(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// The value of cookie `name` in `headers`.
pub(crate) fn cookie(headers: &HeaderMap, name: &str) -> Option<String> {
    headers
        .get_all(axum::http::header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|c| c.trim().split_once('='))
        .find(|(k, _)| *k == name)
        .map(|(_, v)| v.to_string())
}

/// A `Set-Cookie` value: HttpOnly, SameSite=Strict, Path=/, Secure over HTTPS;
/// `max_age` 0 deletes it.
pub(crate) fn set_cookie(name: &str, value: &str, secure: bool, max_age: Option<u64>) -> String {
    let mut c = format!("{name}={value}; Path=/; HttpOnly; SameSite=Strict");
    if secure {
        c.push_str("; Secure");
    }
    if let Some(s) = max_age {
        c.push_str(&format!("; Max-Age={s}"));
    }
    c
}

/// One login.
#[derive(Debug, Clone)]
struct Session {
    csrf: String,
    who: String,
    number: u64,
    created: Instant,
    last: Instant,
}

/// What a handler knows of the session of a request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct SessionView {
    /// The CSRF token its forms carry.
    pub csrf: String,
    /// Who logged in: `administrator`, or a PSK identity.
    pub who: String,
    /// Its number, for the audit.
    pub number: u64,
}

/// The sessions and the failed logins.
#[derive(Debug, Default)]
pub(crate) struct Sessions {
    by_token: HashMap<String, Session>,
    next: u64,
    failures: HashMap<IpAddr, (Instant, u32)>,
    /// When the last failed logins were, from any address (at most
    /// [`GLOBAL_MAX_FAILURES`], oldest first).
    recent_failures: VecDeque<Instant>,
    /// Browsers that have logged in: cookie value to (last good login, failures since).
    trusted: HashMap<String, (Instant, u32)>,
}

/// Why a login is not even tried.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Throttled {
    /// Its address failed too often; wait this long.
    Address(Duration),
    /// Logins failed too often from all addresses; wait this long.
    Everyone(Duration),
}

impl Sessions {
    /// A new session: (cookie token, its view); `None` when the system gives no
    /// random numbers.
    pub(crate) fn create(&mut self, now: Instant, who: &str) -> Option<(String, SessionView)> {
        if self.by_token.len() >= MAX_SESSIONS {
            if let Some(oldest) = self
                .by_token
                .iter()
                .min_by_key(|(_, s)| s.last)
                .map(|(t, _)| t.clone())
            {
                self.by_token.remove(&oldest);
            }
        }
        self.next += 1;
        let token = random_token()?;
        let s = Session {
            csrf: random_token()?,
            who: who.to_string(),
            number: self.next,
            created: now,
            last: now,
        };
        let view = SessionView {
            csrf: s.csrf.clone(),
            who: s.who.clone(),
            number: s.number,
        };
        self.by_token.insert(token.clone(), s);
        Some((token, view))
    }

    /// The session of cookie `token`, if it is alive (and now used).
    pub(crate) fn get(&mut self, token: &str, now: Instant, idle: Duration) -> Option<SessionView> {
        let alive = self.by_token.get(token).is_some_and(|s| {
            now.saturating_duration_since(s.last) < idle
                && now.saturating_duration_since(s.created) < SESSION_LIFE
        });
        if !alive {
            self.by_token.remove(token);
            return None;
        }
        let s = self.by_token.get_mut(token)?;
        s.last = now;
        Some(SessionView {
            csrf: s.csrf.clone(),
            who: s.who.clone(),
            number: s.number,
        })
    }

    /// Ends the session of `token`.
    pub(crate) fn remove(&mut self, token: &str) {
        self.by_token.remove(token);
    }

    /// Whether `ip` must wait before trying again, and how long: its own failures
    /// first, then everyone's unless the browser is trusted (`browser`: its
    /// [`TRUSTED_COOKIE`]).
    pub(crate) fn refused_for(
        &mut self,
        ip: IpAddr,
        browser: Option<&str>,
        now: Instant,
    ) -> Option<Throttled> {
        if let Some(&(since, n)) = self.failures.get(&ip) {
            let elapsed = now.saturating_duration_since(since);
            if elapsed >= FAILURE_WINDOW {
                self.failures.remove(&ip);
            } else if n >= MAX_FAILURES {
                return Some(Throttled::Address(FAILURE_WINDOW - elapsed));
            }
        }
        if browser.is_some_and(|b| self.trusted(b, now)) {
            return None;
        }
        while self
            .recent_failures
            .front()
            .is_some_and(|t| now.saturating_duration_since(*t) >= FAILURE_WINDOW)
        {
            self.recent_failures.pop_front();
        }
        if self.recent_failures.len() < GLOBAL_MAX_FAILURES {
            return None;
        }
        let oldest = *self.recent_failures.front()?;
        Some(Throttled::Everyone(
            FAILURE_WINDOW.saturating_sub(now.saturating_duration_since(oldest)),
        ))
    }

    /// Whether `browser` (a [`TRUSTED_COOKIE`]) is of a browser that logged in here.
    fn trusted(&self, browser: &str, now: Instant) -> bool {
        self.trusted.get(browser).is_some_and(|&(t, n)| {
            n < MAX_FAILURES && now.saturating_duration_since(t) < TRUSTED_LIFE
        })
    }

    /// A failed login from `ip` (from the browser of cookie `browser`).
    pub(crate) fn failed(&mut self, ip: IpAddr, browser: Option<&str>, now: Instant) {
        if self.failures.len() > 10_000 {
            self.failures
                .retain(|_, (t, _)| now.saturating_duration_since(*t) < FAILURE_WINDOW);
        }
        let e = self.failures.entry(ip).or_insert((now, 0));
        if now.saturating_duration_since(e.0) >= FAILURE_WINDOW {
            *e = (now, 0);
        }
        e.1 += 1;
        self.recent_failures.push_back(now);
        while self.recent_failures.len() > GLOBAL_MAX_FAILURES {
            self.recent_failures.pop_front();
        }
        if let Some(t) = browser.and_then(|b| self.trusted.get_mut(b)) {
            t.1 += 1;
        }
    }

    /// A good login from `ip` forgets its failures; the browser is trusted from now
    /// on: the value of its [`TRUSTED_COOKIE`] (the one it has, if it is trusted
    /// already; `None` when the system gives no random numbers).
    pub(crate) fn succeeded(
        &mut self,
        ip: IpAddr,
        browser: Option<&str>,
        now: Instant,
    ) -> Option<String> {
        self.failures.remove(&ip);
        if let Some(b) = browser.filter(|b| self.trusted.contains_key(*b)) {
            self.trusted.insert(b.to_string(), (now, 0));
            return Some(b.to_string());
        }
        self.trusted
            .retain(|_, (t, _)| now.saturating_duration_since(*t) < TRUSTED_LIFE);
        if self.trusted.len() >= MAX_TRUSTED {
            if let Some(oldest) = self
                .trusted
                .iter()
                .min_by_key(|(_, (t, _))| *t)
                .map(|(b, _)| b.clone())
            {
                self.trusted.remove(&oldest);
            }
        }
        let token = random_token()?;
        self.trusted.insert(token.clone(), (now, 0));
        Some(token)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sessions_expire_and_are_bounded() {
        let t0 = Instant::now();
        let mut s = Sessions::default();
        let (tok, view) = s.create(t0, "administrator").unwrap();
        assert_eq!(s.get(&tok, t0, Duration::from_secs(10)), Some(view));
        assert!(s
            .get(&tok, t0 + Duration::from_secs(11), Duration::from_secs(10))
            .is_none());
        for _ in 0..200 {
            s.create(t0, "administrator");
        }
        assert!(s.by_token.len() <= MAX_SESSIONS);
        assert!(s.get("not-a-token", t0, Duration::from_secs(10)).is_none());
    }

    #[test]
    fn failed_logins_lock_an_address_for_a_minute() {
        let t0 = Instant::now();
        let ip: IpAddr = "127.0.0.1".parse().unwrap();
        let mut s = Sessions::default();
        for _ in 0..MAX_FAILURES {
            assert!(s.refused_for(ip, None, t0).is_none());
            s.failed(ip, None, t0);
        }
        assert!(matches!(
            s.refused_for(ip, None, t0 + Duration::from_secs(1)),
            Some(Throttled::Address(_))
        ));
        assert!(s.refused_for(ip, None, t0 + FAILURE_WINDOW).is_none());
    }

    #[test]
    fn failures_from_many_addresses_slow_every_untrusted_login() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut s = Sessions::default();
        // An operator's browser logged in yesterday... well, a moment ago.
        let operator: IpAddr = "10.0.0.9".parse().unwrap();
        let cookie = s.succeeded(operator, None, t0).unwrap();
        // Guesses from many addresses, each below its own limit.
        for n in 0..GLOBAL_MAX_FAILURES as u64 {
            let ip = IpAddr::from([192, 0, 2, (n % 250) as u8 + 1]);
            assert!(s.refused_for(ip, None, at(n * 1000)).is_none(), "{n}");
            s.failed(ip, None, at(n * 1000));
        }
        // Now a new address waits until the oldest failure leaves the window...
        let fresh: IpAddr = "198.51.100.1".parse().unwrap();
        let wait = s.refused_for(fresh, None, at(20_000));
        assert_eq!(wait, Some(Throttled::Everyone(Duration::from_secs(40))));
        assert!(s.refused_for(fresh, Some("forged"), at(20_000)).is_some());
        // ...but the operator's browser does not.
        assert!(s.refused_for(operator, Some(&cookie), at(20_000)).is_none());
        // A sliding window: one failure has left it a minute later.
        assert!(s.refused_for(fresh, None, at(60_000)).is_none());
        // Five failures with the cookie, and it is trusted no more.
        for _ in 0..MAX_FAILURES {
            s.failed(operator, Some(&cookie), at(60_000));
        }
        assert!(s
            .refused_for("10.0.0.10".parse().unwrap(), Some(&cookie), at(60_000))
            .is_some());
        // A good login trusts it again (the same cookie).
        assert_eq!(
            s.succeeded(operator, Some(&cookie), at(61_000)).as_deref(),
            Some(cookie.as_str())
        );
    }

    #[test]
    fn cookies_and_tokens() {
        let mut h = HeaderMap::new();
        h.insert("cookie", "a=1; hartkit_session=abc; b=2".parse().unwrap());
        assert_eq!(cookie(&h, SESSION_COOKIE).as_deref(), Some("abc"));
        assert_eq!(cookie(&h, "c"), None);
        assert!(token_matches("abc", "abc"));
        assert!(!token_matches("", ""));
        assert!(!token_matches("abd", "abc"));
        assert_eq!(random_token().unwrap().len(), 64);
        assert!(set_cookie("x", "y", true, Some(0)).contains("Secure; Max-Age=0"));
        assert!(key_matches("00 11aa", &[0, 0x11, 0xAA]));
        assert!(!key_matches("0011ab", &[0, 0x11, 0xAA]));
        assert!(!key_matches("0011", &[0, 0x11, 0xAA]));
        assert!(!key_matches("zz11aa", &[0, 0x11, 0xAA]));
    }
}
