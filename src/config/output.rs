//! `[output.asterix]`, `[output.sbs]`, `[output.jsonl]`: the track outputs (issue 13). Each is
//! off unless its section is present; `config/default.toml` documents every key.

use super::{bad, check_host_port, int_within, seconds_within, ConfigError};
use serde::Deserialize;

/// The three outputs.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    pub asterix: Option<AsterixConfig>,
    pub sbs: Option<SbsConfig>,
    pub jsonl: Option<JsonlConfig>,
}

impl OutputConfig {
    /// True when any output is configured (the pipeline then broadcasts its updates).
    pub fn any(&self) -> bool {
        self.asterix.is_some() || self.sbs.is_some() || self.jsonl.is_some()
    }
}

/// ASTERIX CAT062 over UDP.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AsterixConfig {
    /// UDP `host:port` destinations, unicast or multicast.
    pub destinations: Vec<String>,
    /// System Area Code and System Identification Code (I062/010).
    pub sac: u8,
    pub sic: u8,
    /// One data block per period with every track updated in it, s.
    pub period_s: f64,
    /// A live track without an update for this long (feed time) is sent every period as
    /// coasting (I062/080 CST), extrapolated along its velocity, until retired, s.
    #[serde(default = "default_coast_after_s")]
    pub coast_after_s: f64,
    /// Service identification (I062/015).
    #[serde(default = "default_service_id")]
    pub service_id: u8,
    /// System reference point: with it, records carry I062/100 (Cartesian position, m:
    /// east and north in the plane tangent to the WGS-84 ellipsoid at this point).
    #[serde(default)]
    pub system_ref: Option<SystemRef>,
    /// Time to live of multicast datagrams (hops).
    #[serde(default = "default_multicast_ttl")]
    pub multicast_ttl: u32,
    /// Largest datagram, bytes: a period's records are split into as many data blocks.
    #[serde(default = "default_max_datagram_bytes")]
    pub max_datagram_bytes: usize,
}

/// The system reference point of I062/100.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SystemRef {
    pub lat_deg: f64,
    pub lon_deg: f64,
}

fn default_coast_after_s() -> f64 {
    5.0
}
fn default_service_id() -> u8 {
    1
}
fn default_multicast_ttl() -> u32 {
    1
}
fn default_max_datagram_bytes() -> usize {
    1400
}
fn default_max_clients() -> usize {
    64
}
fn default_write_timeout_s() -> f64 {
    10.0
}
fn default_client_queue() -> usize {
    1024
}

/// SBS BaseStation text on TCP.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SbsConfig {
    /// Address the server listens on (30003 by convention).
    pub listen: String,
    /// Clients connected at once; one more is closed at once.
    #[serde(default = "default_max_clients")]
    pub max_clients: usize,
    /// A client whose socket takes nothing for this long is dropped, s.
    #[serde(default = "default_write_timeout_s")]
    pub write_timeout_s: f64,
    /// Chunks (up to 256 updates each) a client may fall behind before it is dropped.
    #[serde(default = "default_client_queue")]
    pub client_queue: usize,
}

/// JSON lines (the `--tracks-out` Track object per update) on TCP.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JsonlConfig {
    pub listen: String,
    #[serde(default = "default_max_clients")]
    pub max_clients: usize,
    #[serde(default = "default_write_timeout_s")]
    pub write_timeout_s: f64,
    #[serde(default = "default_client_queue")]
    pub client_queue: usize,
    /// Only tracks in `south,west,north,east` (degrees), as `GET /api/v1/tracks?bbox=`.
    #[serde(default)]
    pub bbox: Option<String>,
    /// Only tracks of these mode labels, as `GET /api/v1/tracks?mode=`.
    #[serde(default)]
    pub modes: Option<Vec<String>>,
}

/// The mode labels a filter may name.
pub const MODE_LABELS: [&str; 5] = ["CV", "CA", "CT", "CH", "CHCA"];

/// A latitude/longitude box; `west > east` crosses the antimeridian.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BBox {
    pub south: f64,
    pub west: f64,
    pub north: f64,
    pub east: f64,
}

impl BBox {
    /// `south,west,north,east` in degrees.
    pub fn parse(s: &str) -> Option<Self> {
        let mut it = s.split(',').map(|p| p.trim().parse::<f64>());
        let (south, west, north, east) = match (it.next(), it.next(), it.next(), it.next()) {
            (Some(Ok(a)), Some(Ok(b)), Some(Ok(c)), Some(Ok(d))) => (a, b, c, d),
            _ => return None,
        };
        if it.next().is_some() {
            return None;
        }
        let lat_ok = |x: f64| (-90.0..=90.0).contains(&x);
        let lon_ok = |x: f64| (-180.0..=180.0).contains(&x);
        if !(lat_ok(south) && lat_ok(north) && lon_ok(west) && lon_ok(east)) || south > north {
            return None;
        }
        Some(Self {
            south,
            west,
            north,
            east,
        })
    }

    pub fn contains(&self, lat: f64, lon: f64) -> bool {
        let lon_in = if self.west <= self.east {
            (self.west..=self.east).contains(&lon)
        } else {
            lon >= self.west || lon <= self.east
        };
        (self.south..=self.north).contains(&lat) && lon_in
    }
}

fn check_listen(key: &str, listen: &str) -> Result<(), ConfigError> {
    if listen.parse::<std::net::SocketAddr>().is_err() {
        return Err(bad(
            key,
            format!("{listen:?} is not an address like 127.0.0.1:30003"),
        ));
    }
    Ok(())
}

fn check_tcp(
    section: &str,
    listen: &str,
    max_clients: usize,
    write_timeout_s: f64,
    client_queue: usize,
) -> Result<(), ConfigError> {
    check_listen(&format!("{section}.listen"), listen)?;
    int_within(&format!("{section}.max_clients"), max_clients, 1, 4096)?;
    seconds_within(
        &format!("{section}.write_timeout_s"),
        write_timeout_s,
        0.1,
        3600.0,
    )?;
    int_within(&format!("{section}.client_queue"), client_queue, 1, 65_536)
}

impl OutputConfig {
    /// Range checks, naming the key of a refused value.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if let Some(a) = &self.asterix {
            if a.destinations.is_empty() {
                return Err(bad(
                    "output.asterix.destinations",
                    "needs at least one host:port",
                ));
            }
            for (i, d) in a.destinations.iter().enumerate() {
                check_host_port(d)
                    .map_err(|p| bad(&format!("output.asterix.destinations[{i}]"), p))?;
            }
            seconds_within("output.asterix.period_s", a.period_s, 0.01, 3600.0)?;
            seconds_within(
                "output.asterix.coast_after_s",
                a.coast_after_s,
                0.1,
                86_400.0,
            )?;
            int_within("output.asterix.multicast_ttl", a.multicast_ttl, 0, 255)?;
            int_within(
                "output.asterix.max_datagram_bytes",
                a.max_datagram_bytes,
                256,
                65_507,
            )?;
            if let Some(r) = a.system_ref {
                if !(-90.0..=90.0).contains(&r.lat_deg) {
                    return Err(bad(
                        "output.asterix.system_ref.lat_deg",
                        "must be within -90..90",
                    ));
                }
                if !(-180.0..=180.0).contains(&r.lon_deg) {
                    return Err(bad(
                        "output.asterix.system_ref.lon_deg",
                        "must be within -180..180",
                    ));
                }
            }
        }
        if let Some(s) = &self.sbs {
            check_tcp(
                "output.sbs",
                &s.listen,
                s.max_clients,
                s.write_timeout_s,
                s.client_queue,
            )?;
        }
        if let Some(j) = &self.jsonl {
            check_tcp(
                "output.jsonl",
                &j.listen,
                j.max_clients,
                j.write_timeout_s,
                j.client_queue,
            )?;
            if let Some(b) = &j.bbox {
                if BBox::parse(b).is_none() {
                    return Err(bad(
                        "output.jsonl.bbox",
                        format!("{b:?}: expected south,west,north,east in degrees"),
                    ));
                }
            }
            for (i, m) in j.modes.iter().flatten().enumerate() {
                if !MODE_LABELS.contains(&m.as_str()) {
                    return Err(bad(
                        &format!("output.jsonl.modes[{i}]"),
                        format!("unknown {m:?}; expected one of {}", MODE_LABELS.join(", ")),
                    ));
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::config::Config;

    #[test]
    fn the_contract_keys_parse_and_are_off_by_default() {
        let c = Config::default_config().unwrap();
        assert!(!c.output.any());
        let c = Config::from_toml_str(
            "[output.asterix]\ndestinations = [\"127.0.0.1:8600\"]\nsac = 25\nsic = 1\nperiod_s = 1.0\n\
             [output.sbs]\nlisten = \"127.0.0.1:30003\"\n\
             [output.jsonl]\nlisten = \"127.0.0.1:30154\"\n",
        )
        .unwrap();
        let a = c.output.asterix.unwrap();
        assert_eq!((a.sac, a.sic, a.period_s), (25, 1, 1.0));
        assert_eq!(a.destinations, vec!["127.0.0.1:8600".to_string()]);
        assert_eq!(c.output.sbs.unwrap().listen, "127.0.0.1:30003");
        assert_eq!(c.output.jsonl.unwrap().listen, "127.0.0.1:30154");
    }

    #[test]
    fn bad_outputs_name_their_key() {
        crate::config::assert_refused_naming(&[
            (
                "[output.asterix]\ndestinations = []\nsac = 1\nsic = 1\nperiod_s = 1.0\n",
                "output.asterix.destinations",
            ),
            (
                "[output.asterix]\ndestinations = [\"x\"]\nsac = 1\nsic = 1\nperiod_s = 1.0\n",
                "output.asterix.destinations[0]",
            ),
            (
                "[output.asterix]\ndestinations = [\"h:1\"]\nsac = 256\nsic = 1\nperiod_s = 1.0\n",
                "sac",
            ),
            (
                "[output.asterix]\ndestinations = [\"h:1\"]\nsac = 1\nsic = 1\nperiod_s = 0.0\n",
                "output.asterix.period_s",
            ),
            ("[output.sbs]\nlisten = \"nowhere\"\n", "output.sbs.listen"),
            (
                "[output.sbs]\nlisten = \"127.0.0.1:1\"\nmax_clients = 0\n",
                "output.sbs.max_clients",
            ),
            (
                "[output.jsonl]\nlisten = \"127.0.0.1:1\"\nbbox = \"1,2,3\"\n",
                "output.jsonl.bbox",
            ),
            (
                "[output.jsonl]\nlisten = \"127.0.0.1:1\"\nmodes = [\"XX\"]\n",
                "output.jsonl.modes[0]",
            ),
            ("[output.foo]\nlisten = \"127.0.0.1:1\"\n", "foo"),
        ]);
    }
}
