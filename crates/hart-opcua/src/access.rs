//! Who may connect to the OPC UA front end, and who may call its methods.
//!
//! The rules ([`Rules`]) are a pure function of the configuration (security, whether
//! users are configured, `--read-only`), the endpoint a session came in on
//! ([`Channel`]) and its identity ([`Token`]):
//!
//! | security         | users | token on endpoint             | connects | calls methods  |
//! |------------------|-------|-------------------------------|----------|----------------|
//! | `none`           | no    | anonymous on None             | yes      | yes            |
//! | `none`           | yes   | (refused at start-up)         |          |                |
//! | `basic256sha256` | no    | anonymous on Basic256Sha256   | yes      | yes            |
//! | `basic256sha256` | yes   | user on Basic256Sha256        | yes      | yes            |
//! | `basic256sha256` | yes   | anonymous on Basic256Sha256   | no       |                |
//! | `both`           | no    | anonymous on Basic256Sha256   | yes      | yes            |
//! | `both`           | no    | anonymous on None             | yes      | no (reads)     |
//! | `both`           | yes   | user on Basic256Sha256        | yes      | yes            |
//! | `both`           | yes   | anonymous on None             | yes      | no (reads)     |
//! | any              | any   | user on None                  | no       |                |
//!
//! `--read-only` refuses every method call. Variables are never written, by anyone.
//! Basic256Sha256 only ever admits clients whose certificate is in the trust list
//! (see [`crate::trust`]), so with no users that certificate is the credential; a
//! None endpoint next to it (`both`) is unauthenticated, so it only reads: otherwise
//! anyone could go round the trust list.
//!
//! [`GatewayAuth`] is the async-opcua [`AuthManager`] that applies them when a session
//! is activated (user names and passwords are checked here, without an early exit on
//! the first wrong byte) and when a client looks at a method's UserExecutable or a
//! variable's UserAccessLevel; the node manager asks [`Rules::may_call`] again, with
//! the session's endpoint, before each call.

use async_trait::async_trait;
use opcua::crypto::SecurityPolicy;
use opcua::server::address_space::AccessLevel;
use opcua::server::authenticator::{AuthManager, DefaultAuthenticator, Password, UserToken};
use opcua::server::{ServerEndpoint, ServerUserToken, ANONYMOUS_USER_TOKEN_ID};
use opcua::types::{Error, NodeId, StatusCode, UserTokenPolicy, UserTokenType};
use subtle::ConstantTimeEq;

/// The endpoint a session came in on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    /// SecurityPolicy None: neither signed nor encrypted.
    None,
    /// Basic256Sha256, signed and encrypted, with a trusted client certificate.
    Secure,
}

impl Channel {
    /// The channel of a session on an endpoint of this security policy.
    pub fn of_policy(policy: SecurityPolicy) -> Channel {
        if policy == SecurityPolicy::None {
            Channel::None
        } else {
            Channel::Secure
        }
    }

    /// The channel of a session whose security policy URI is `uri`.
    pub fn of_uri(uri: &str) -> Channel {
        Channel::of_policy(SecurityPolicy::from_uri(uri))
    }
}

/// A session's identity, as far as the rules care.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Token {
    /// No user name.
    Anonymous,
    /// A configured user, whose password was right.
    User,
}

/// The access rules of one configuration (see the module's table).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rules {
    /// Endpoints offered.
    pub security: Security,
    /// Whether any users are configured.
    pub users: bool,
    /// `--read-only`: no method calls at all.
    pub read_only: bool,
}

impl Rules {
    /// Whether an endpoint of this channel is offered.
    pub fn offers(&self, channel: Channel) -> bool {
        match channel {
            Channel::None => matches!(self.security, Security::None | Security::Both),
            Channel::Secure => matches!(self.security, Security::Basic256Sha256 | Security::Both),
        }
    }

    /// Whether a session of `token` may be activated on `channel` (for a user: with
    /// the right password).
    pub fn may_connect(&self, channel: Channel, token: Token) -> bool {
        if !self.offers(channel) {
            return false;
        }
        match (channel, token) {
            // A password over SecurityPolicy None would travel in clear.
            (Channel::None, Token::User) => false,
            // Users configured with security none is refused at start-up; should it
            // come here anyway, nobody gets in.
            (Channel::None, Token::Anonymous) => !(self.users && self.security == Security::None),
            (Channel::Secure, Token::User) => self.users,
            (Channel::Secure, Token::Anonymous) => !self.users,
        }
    }

    /// Whether a session of `token` on `channel` may call methods (which write devices).
    pub fn may_call(&self, channel: Channel, token: Token) -> bool {
        if self.read_only || !self.may_connect(channel, token) {
            return false;
        }
        match (channel, token) {
            (_, Token::User) => true,
            (Channel::Secure, Token::Anonymous) => !self.users,
            // Anonymous without security writes only where None is all there is (a
            // gateway on localhost, tests).
            (Channel::None, Token::Anonymous) => !self.users && self.security == Security::None,
        }
    }

    /// Whether a session of `token` may call methods on some endpoint (what
    /// UserExecutable shows: the token does not say which endpoint the session is on).
    pub fn may_call_somewhere(&self, token: Token) -> bool {
        self.may_call(Channel::None, token) || self.may_call(Channel::Secure, token)
    }
}

/// The prefix of a configured user's async-opcua user token (so that no user name can
/// pass for the anonymous token's id).
const USER_PREFIX: &str = "user:";

/// The identity of a session's user token, as the audit names it: the user name, or
/// `anonymous`.
pub fn identity(token: &UserToken) -> String {
    match token.0.strip_prefix(USER_PREFIX) {
        Some(name) if !token.is_anonymous() => name.to_string(),
        _ => "anonymous".to_string(),
    }
}

/// The rules' view of an async-opcua user token.
pub fn token_kind(token: &UserToken) -> Token {
    if !token.is_anonymous() && token.0.starts_with(USER_PREFIX) {
        Token::User
    } else {
        Token::Anonymous
    }
}

/// The user token ids an endpoint of `channel` lists (what async-opcua's configuration
/// and its endpoint descriptions are built from).
pub(crate) fn endpoint_token_ids(
    rules: &Rules,
    users: &[(String, String)],
    channel: Channel,
) -> Vec<String> {
    let mut ids = vec![];
    if rules.may_connect(channel, Token::Anonymous) {
        ids.push(ANONYMOUS_USER_TOKEN_ID.to_string());
    }
    if rules.may_connect(channel, Token::User) {
        ids.extend(users.iter().map(|(u, _)| format!("{USER_PREFIX}{u}")));
    }
    ids
}

/// The configured users as async-opcua's configuration keeps them (id, token).
pub(crate) fn user_tokens(users: &[(String, String)]) -> Vec<(String, ServerUserToken)> {
    users
        .iter()
        .map(|(u, p)| {
            (
                format!("{USER_PREFIX}{u}"),
                ServerUserToken::user_pass(u.as_str(), p.as_str()),
            )
        })
        .collect()
}

/// The gateway's [`AuthManager`]: anonymous and user-name tokens by [`Rules`], passwords
/// compared in constant time, methods executable by the rules, variables never writable.
pub struct GatewayAuth {
    rules: Rules,
    users: Vec<(String, String)>,
    /// Only for the user token policies' ids (which async-opcua keeps private).
    policies: DefaultAuthenticator,
}

impl GatewayAuth {
    /// The authenticator of `rules` with these users (name, password).
    pub fn new(rules: Rules, users: Vec<(String, String)>) -> GatewayAuth {
        let policies = DefaultAuthenticator::new(user_tokens(&users).into_iter().collect());
        GatewayAuth {
            rules,
            users,
            policies,
        }
    }

    /// Whether `name` and `password` are a configured user's. Every user is compared,
    /// each in constant time (only the lengths may show), whatever matched before.
    fn check_password(&self, name: &str, password: &str) -> bool {
        let mut found = subtle::Choice::from(0);
        for (n, p) in &self.users {
            found |= n.as_bytes().ct_eq(name.as_bytes()) & p.as_bytes().ct_eq(password.as_bytes());
        }
        found.into()
    }
}

fn channel_of(endpoint: &ServerEndpoint) -> Channel {
    Channel::of_policy(endpoint.security_policy())
}

#[async_trait]
impl AuthManager for GatewayAuth {
    async fn authenticate_anonymous_token(&self, endpoint: &ServerEndpoint) -> Result<(), Error> {
        if self
            .rules
            .may_connect(channel_of(endpoint), Token::Anonymous)
        {
            return Ok(());
        }
        tracing::warn!(
            "opcua: an anonymous session on the {} endpoint refused",
            endpoint.security_policy
        );
        Err(Error::new(
            StatusCode::BadIdentityTokenRejected,
            "anonymous access is not offered on this endpoint: log in with a user name and \
             password on the Basic256Sha256 endpoint",
        ))
    }

    async fn authenticate_username_identity_token(
        &self,
        endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        if !self.rules.may_connect(channel_of(endpoint), Token::User) {
            tracing::warn!(
                "opcua: user {username:?} refused: no user logs in on the {} endpoint",
                endpoint.security_policy
            );
            return Err(Error::new(
                StatusCode::BadIdentityTokenRejected,
                "user names are only taken on the Basic256Sha256 endpoint, and only when users \
                 are configured",
            ));
        }
        if self.check_password(username, password.get()) {
            tracing::info!("opcua: user {username:?} logged in");
            return Ok(UserToken(format!("{USER_PREFIX}{username}")));
        }
        tracing::warn!("opcua: user {username:?} refused: wrong user name or password");
        Err(Error::new(
            StatusCode::BadUserAccessDenied,
            "wrong user name or password",
        ))
    }

    fn effective_user_access_level(
        &self,
        _token: &UserToken,
        user_access_level: AccessLevel,
        node_id: &NodeId,
    ) -> AccessLevel {
        // The gateway's variables are never written (the node manager refuses them
        // too); the server's own (namespace 0) are async-opcua's business.
        if node_id.namespace == 0 {
            user_access_level
        } else {
            user_access_level
                - (AccessLevel::CURRENT_WRITE
                    | AccessLevel::HISTORY_WRITE
                    | AccessLevel::SEMANTIC_CHANGE
                    | AccessLevel::STATUS_WRITE
                    | AccessLevel::TIMESTAMP_WRITE)
        }
    }

    fn is_user_executable(&self, token: &UserToken, method_id: &NodeId) -> bool {
        // The server's own methods (namespace 0: GetMonitoredItems, ...) touch no
        // device; the gateway's write devices.
        method_id.namespace == 0 || self.rules.may_call_somewhere(token_kind(token))
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        let channel = channel_of(endpoint);
        self.policies
            .user_token_policies(endpoint)
            .into_iter()
            .filter(|p| match p.token_type {
                UserTokenType::Anonymous => self.rules.may_connect(channel, Token::Anonymous),
                UserTokenType::UserName => self.rules.may_connect(channel, Token::User),
                _ => false,
            })
            .collect()
    }
}

/// Endpoint security.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Security {
    /// SecurityPolicy None only, anonymous (for a gateway on localhost, and tests); no
    /// users (their passwords would travel in clear).
    None,
    /// Basic256Sha256, signed and encrypted, with the gateway's self-signed certificate,
    /// for clients whose certificate is in the trust list; users by name and password
    /// when any are configured, else anonymous.
    Basic256Sha256,
    /// Both endpoints; anonymous sessions on the None one only read.
    Both,
}

impl Security {
    /// `none`, `basic256sha256`, `both`.
    pub fn name(self) -> &'static str {
        match self {
            Security::None => "none",
            Security::Basic256Sha256 => "basic256sha256",
            Security::Both => "both",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SECURITIES: [Security; 3] = [Security::None, Security::Basic256Sha256, Security::Both];

    fn endpoint(rules: &Rules, users: &[(String, String)], channel: Channel) -> ServerEndpoint {
        let ids = endpoint_token_ids(rules, users, channel);
        match channel {
            Channel::None => ServerEndpoint::new_none("/", &ids),
            Channel::Secure => ServerEndpoint::new_basic256sha256_sign_encrypt("/", &ids),
        }
    }

    /// What a client gets: `None` refused at connection, else whether it may call.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum Got {
        NoEndpoint,
        Refused,
        Reads,
        Calls,
    }

    /// The whole table: security × users × endpoint × token (anonymous, right
    /// password, wrong password) → what the real authenticator lets happen.
    #[tokio::test]
    async fn the_rules_table() {
        use Channel as C;
        use Got::*;
        #[rustfmt::skip]
        let table: &[(Security, bool, Channel, &str, Got)] = &[
            // security, users, endpoint, token, outcome
            (Security::None, false, C::None, "anonymous", Calls),
            (Security::None, false, C::None, "right", Refused),
            (Security::None, false, C::Secure, "anonymous", NoEndpoint),
            // Refused at start-up (Config::check); the rules let nobody in either.
            (Security::None, true, C::None, "anonymous", Refused),
            (Security::None, true, C::None, "right", Refused),
            (Security::Basic256Sha256, false, C::Secure, "anonymous", Calls),
            (Security::Basic256Sha256, false, C::Secure, "right", Refused),
            (Security::Basic256Sha256, false, C::None, "anonymous", NoEndpoint),
            (Security::Basic256Sha256, true, C::Secure, "anonymous", Refused),
            (Security::Basic256Sha256, true, C::Secure, "right", Calls),
            (Security::Basic256Sha256, true, C::Secure, "wrong", Refused),
            (Security::Basic256Sha256, true, C::Secure, "nobody", Refused),
            (Security::Basic256Sha256, true, C::None, "anonymous", NoEndpoint),
            (Security::Both, false, C::None, "anonymous", Reads),
            (Security::Both, false, C::Secure, "anonymous", Calls),
            (Security::Both, false, C::Secure, "right", Refused),
            (Security::Both, true, C::None, "anonymous", Reads),
            (Security::Both, true, C::None, "right", Refused),
            (Security::Both, true, C::Secure, "anonymous", Refused),
            (Security::Both, true, C::Secure, "right", Calls),
            (Security::Both, true, C::Secure, "wrong", Refused),
        ];
        for &(security, with_users, channel, who, expect) in table {
            for read_only in [false, true] {
                let users: Vec<(String, String)> = if with_users {
                    vec![
                        ("operator".into(), "s3cret".into()),
                        ("eng".into(), "other".into()),
                    ]
                } else {
                    vec![]
                };
                let rules = Rules {
                    security,
                    users: with_users,
                    read_only,
                };
                let auth = GatewayAuth::new(rules, users.clone());
                let got = if !rules.offers(channel) {
                    NoEndpoint
                } else {
                    let ep = endpoint(&rules, &users, channel);
                    let token = match who {
                        "anonymous" => auth
                            .authenticate_anonymous_token(&ep)
                            .await
                            .map(|_| UserToken(ANONYMOUS_USER_TOKEN_ID.into())),
                        "right" => {
                            auth.authenticate_username_identity_token(
                                &ep,
                                "operator",
                                &Password::new("s3cret".into()),
                            )
                            .await
                        }
                        "wrong" => {
                            auth.authenticate_username_identity_token(
                                &ep,
                                "operator",
                                &Password::new("other".into()),
                            )
                            .await
                        }
                        _ => {
                            auth.authenticate_username_identity_token(
                                &ep,
                                "nobody",
                                &Password::new("s3cret".into()),
                            )
                            .await
                        }
                    };
                    // What the endpoint description offers agrees with what is accepted.
                    let offered = auth.user_token_policies(&ep);
                    let kind = if who == "anonymous" {
                        UserTokenType::Anonymous
                    } else {
                        UserTokenType::UserName
                    };
                    let listed = offered.iter().any(|p| p.token_type == kind);
                    match token {
                        Err(_) => {
                            assert!(
                                !listed || matches!(who, "wrong" | "nobody"),
                                "{security:?} users {with_users} {channel:?} {who}: offered but refused"
                            );
                            Refused
                        }
                        Ok(t) => {
                            assert!(
                                listed,
                                "{security:?} {channel:?} {who}: accepted, not offered"
                            );
                            let method = NodeId::new(2, "HART/sim/TT-200/SetDamping");
                            let calls = rules.may_call(channel, token_kind(&t));
                            // UserExecutable never says no where the call goes through.
                            assert!(!calls || auth.is_user_executable(&t, &method));
                            assert_eq!(
                                identity(&t),
                                if who == "anonymous" {
                                    "anonymous"
                                } else {
                                    "operator"
                                }
                            );
                            if calls {
                                Calls
                            } else {
                                Reads
                            }
                        }
                    }
                };
                let expect = match (expect, read_only) {
                    (Calls, true) => Reads,
                    (e, _) => e,
                };
                assert_eq!(
                    got, expect,
                    "{security:?}, users {with_users}, read-only {read_only}, {channel:?} endpoint, {who}"
                );
            }
        }
    }

    /// Every configuration: anonymous without security never calls when there is a
    /// secure endpoint or users; a user never logs in without security; nothing is
    /// writable.
    #[test]
    fn no_side_doors() {
        for security in SECURITIES {
            for users in [false, true] {
                for read_only in [false, true] {
                    let r = Rules {
                        security,
                        users,
                        read_only,
                    };
                    assert!(!r.may_connect(Channel::None, Token::User));
                    if users || security == Security::Both {
                        assert!(!r.may_call(Channel::None, Token::Anonymous), "{r:?}");
                    }
                    if users {
                        assert!(!r.may_call_somewhere(Token::Anonymous), "{r:?}");
                    }
                    if read_only {
                        assert!(!r.may_call_somewhere(Token::User));
                        assert!(!r.may_call_somewhere(Token::Anonymous));
                    }
                }
            }
        }
        let auth = GatewayAuth::new(
            Rules {
                security: Security::None,
                users: false,
                read_only: false,
            },
            vec![],
        );
        let anon = UserToken(ANONYMOUS_USER_TOKEN_ID.into());
        let level = AccessLevel::CURRENT_READ | AccessLevel::CURRENT_WRITE;
        assert_eq!(
            auth.effective_user_access_level(
                &anon,
                level,
                &NodeId::new(2, "HART/sim/TT-200/Damping")
            )
            .bits(),
            AccessLevel::CURRENT_READ.bits()
        );
    }

    #[test]
    fn identities() {
        assert_eq!(
            identity(&UserToken(ANONYMOUS_USER_TOKEN_ID.into())),
            "anonymous"
        );
        assert_eq!(identity(&UserToken("user:operator".into())), "operator");
        assert_eq!(token_kind(&UserToken("ANONYMOUS".into())), Token::Anonymous);
        // A user named like the anonymous token is still a user (prefixed).
        assert_eq!(token_kind(&UserToken("user:ANONYMOUS".into())), Token::User);
        assert_eq!(token_kind(&UserToken("operator".into())), Token::Anonymous);
    }
}
