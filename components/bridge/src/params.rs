//! `[node.params]` of a `bridge` stage, validated, and the Zenoh configuration they make.

use bowden_interfaces::config::ConfigError;
use serde::Deserialize;

/// Bridge parameters.
///
/// ```toml
/// [[node]]
/// name = "bridge"
/// [node.params]
/// listen = ["tcp/0.0.0.0:7447"]           # this side accepts the peer (vision PC) ...
/// # connect = ["tcp/192.168.1.10:7447"]   # ... or dials it (control PC)
/// export = ["bowden/plant_state"]         # iceoryx2 → network
/// import = ["bowden/joint_estimate"]      # network → iceoryx2
/// ```
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BridgeParams {
    /// Endpoints this side accepts peers on (`tcp/HOST:PORT`). Nothing listens unless given.
    #[serde(default)]
    pub listen: Vec<String>,
    /// Endpoints of peers this side dials (`tcp/HOST:PORT`); retried until they answer.
    #[serde(default)]
    pub connect: Vec<String>,
    /// Services read here and sent to the peer (validated by the pipeline config).
    #[serde(default)]
    pub export: Vec<String>,
    /// Services received from the peer and published here.
    #[serde(default)]
    pub import: Vec<String>,
    /// Zenoh key prefix: the key of a service is `<key_prefix>/<service>`. Two robots on one
    /// network use two prefixes; both sides of one link must use the same.
    #[serde(default = "default_key_prefix")]
    pub key_prefix: String,
    /// A peer that sends nothing (not even Zenoh's keep-alives) for this long is lost, ms.
    /// A peer whose process dies is lost at once (its TCP connection closes).
    #[serde(default = "default_lease_ms")]
    pub lease_ms: u64,
    /// Without any peer this long after start-up, the bridge reports a fault (a wrong
    /// endpoint, a firewall), ms.
    #[serde(default = "default_peer_timeout_ms")]
    pub peer_timeout_ms: u64,
    /// Zenoh's low-latency transport (no batching, no priority queues): lower latency for
    /// control samples, but it does not fragment, so it cannot carry RGBD frames. Default: on
    /// unless this bridge carries frames (run a second bridge for frames to have both). Both
    /// sides of a link must agree.
    #[serde(default)]
    pub low_latency: Option<bool>,
    /// Largest RGBD frame payload imported, bytes (sizes the shared-memory frame publisher).
    #[serde(default = "default_max_frame_bytes")]
    pub max_frame_bytes: usize,
}

fn default_key_prefix() -> String {
    "bowden".into()
}
fn default_lease_ms() -> u64 {
    1000
}
fn default_peer_timeout_ms() -> u64 {
    10_000
}
fn default_max_frame_bytes() -> usize {
    bowden_interfaces::RgbdFrameHeader::payload_len_for(640, 480)
}

impl BridgeParams {
    /// Whether a frame service crosses this bridge.
    pub fn carries_frames(&self) -> bool {
        self.export
            .iter()
            .chain(self.import.iter())
            .any(|s| s == bowden_interfaces::services::RGBD_FRAME)
    }

    /// Whether the session uses Zenoh's low-latency transport.
    pub fn low_latency(&self) -> bool {
        self.low_latency.unwrap_or(!self.carries_frames())
    }

    /// Checks what the pipeline config does not: endpoints, key prefix, timings. `origin`
    /// names the parameters in errors (e.g. "configs/bridge-a.toml: [node.params] of `link`").
    pub fn validate(&self, origin: impl std::fmt::Display) -> Result<(), ConfigError> {
        let bad = |field: &str, problem: String| Err(ConfigError::invalid(&origin, field, problem));
        if self.low_latency == Some(true) && self.carries_frames() {
            return bad(
                "low_latency",
                "`true` with `bowden/rgbd_frame`: Zenoh's low-latency transport does not fragment and \
                 cannot carry a frame; leave `low_latency` unset or false, or bridge frames with a second \
                 bridge stage"
                    .into(),
            );
        }
        if self.listen.is_empty() && self.connect.is_empty() {
            return bad(
                "listen",
                "a bridge needs `listen = [...]` or `connect = [...]` endpoints: without either it can \
                 never reach its peer"
                    .into(),
            );
        }
        for (key, list) in [("listen", &self.listen), ("connect", &self.connect)] {
            for e in list.iter() {
                if let Err(p) = check_endpoint(e) {
                    return bad(key, format!("endpoint `{e}`: {p}"));
                }
            }
        }
        let kp = &self.key_prefix;
        if kp.is_empty()
            || kp.starts_with('/')
            || kp.ends_with('/')
            || kp.contains("//")
            || !kp
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-' || b == b'/')
        {
            return bad(
                "key_prefix",
                format!("`{kp}`: must be chunks of [A-Za-z0-9_-] separated by single `/`"),
            );
        }
        if !(100..=60_000).contains(&self.lease_ms) {
            return bad("lease_ms", format!("{}: must be in 100..=60000", self.lease_ms));
        }
        if self.peer_timeout_ms == 0 {
            return bad("peer_timeout_ms", "must be positive".into());
        }
        if self.max_frame_bytes == 0 || self.max_frame_bytes > 64 << 20 {
            return bad(
                "max_frame_bytes",
                format!("{}: must be in 1..=67108864", self.max_frame_bytes),
            );
        }
        Ok(())
    }

    /// The Zenoh key a service travels under.
    pub fn key_of(&self, service: &str) -> String {
        format!("{}/{service}", self.key_prefix)
    }

    /// The liveliness key of a bridge session (`zid`), and the selector of all bridges on
    /// this key prefix.
    pub fn token_key(&self, zid: &str) -> String {
        format!("{}/bridges/{zid}", self.key_prefix)
    }

    pub fn tokens_selector(&self) -> String {
        self.token_key("*")
    }

    /// A peer-to-peer Zenoh session that opens exactly the configured endpoints: no multicast
    /// scouting, no gossip, no listener unless `listen` is given.
    pub fn zenoh_config(&self) -> Result<zenoh::Config, ConfigError> {
        let list = |v: &[String]| {
            format!(
                "[{}]",
                v.iter().map(|e| format!("\"{e}\"")).collect::<Vec<_>>().join(",")
            )
        };
        let mut c = zenoh::Config::default();
        let mut set = |k: &str, v: String| {
            c.insert_json5(k, &v)
                .map_err(|e| ConfigError::invalid("the Zenoh session config", k, format!("{v}: {e}")))
        };
        set("mode", "\"peer\"".into())?;
        set("listen/endpoints", list(&self.listen))?;
        set("connect/endpoints", list(&self.connect))?;
        // A lost peer is re-dialled quickly, forever.
        set(
            "connect/retry",
            "{ period_init_ms: 200, period_max_ms: 1000, period_increase_factor: 2.0 }".into(),
        )?;
        set("scouting/multicast/enabled", "false".into())?;
        set("scouting/gossip/enabled", "false".into())?;
        set("transport/link/tx/lease", self.lease_ms.to_string())?;
        if self.low_latency() {
            set("transport/unicast/lowlatency", "true".into())?;
            set("transport/unicast/qos/enabled", "false".into())?;
        }
        Ok(c)
    }
}

fn check_endpoint(e: &str) -> Result<(), String> {
    let Some(addr) = e.strip_prefix("tcp/") else {
        return Err("must be `tcp/HOST:PORT` (bowden builds Zenoh with its TCP transport only)".into());
    };
    let Some((host, port)) = addr.rsplit_once(':') else {
        return Err("missing `:PORT`".into());
    };
    if host.is_empty() {
        return Err("missing host".into());
    }
    port.parse::<u16>()
        .map_err(|_| format!("port `{port}` is not a number in 0..=65535"))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(t: &str) -> Result<BridgeParams, String> {
        let p: BridgeParams = toml::from_str(t).map_err(|e| e.to_string())?;
        p.validate("test").map_err(|e| e.to_string())?;
        Ok(p)
    }

    #[test]
    fn bad_parameters_are_named() {
        let e = parse("export = [\"bowden/plant_state\"]").unwrap_err();
        assert!(e.contains("listen") && e.contains("connect"), "{e}");
        let e = parse("listen = [\"udp/1.2.3.4:7\"]").unwrap_err();
        assert!(e.contains("`listen`: endpoint `udp/1.2.3.4:7`"), "{e}");
        let e = parse("connect = [\"tcp/host\"]").unwrap_err();
        assert!(e.contains(":PORT"), "{e}");
        let e = parse("connect = [\"tcp/host:99999\"]").unwrap_err();
        assert!(e.contains("99999"), "{e}");
        let e = parse("connect = [\"tcp/h:1\"]\nkey_prefix = \"a/*\"").unwrap_err();
        assert!(e.contains("key_prefix"), "{e}");
        let e = parse("connect = [\"tcp/h:1\"]\nlease_ms = 5").unwrap_err();
        assert!(e.contains("lease_ms"), "{e}");
        let e = parse("connect = [\"tcp/h:1\"]\nlow_latency = true\nimport = [\"bowden/rgbd_frame\"]").unwrap_err();
        assert!(e.contains("fragment"), "{e}");
        let e = parse("connect = [\"tcp/h:1\"]\nlisten_on = 1").unwrap_err();
        assert!(e.contains("listen_on"), "{e}");
        let p = parse("connect = [\"tcp/[::1]:7447\"]\nkey_prefix = \"lab/arm2\"").unwrap();
        assert_eq!(p.key_of("bowden/joint_estimate"), "lab/arm2/bowden/joint_estimate");
        if let Err(e) = p.zenoh_config() {
            panic!("{e}");
        }
    }
}
