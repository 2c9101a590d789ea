//! `[map]`: the live map page at `/` (issue 12). Its base layer is the world outline embedded
//! in the binary, so the page needs no network; a tile server is the user's choice, off by
//! default. `config/default.toml` documents every key.

use super::{bad, int_within, ConfigError, Short};
use serde::Deserialize;

/// The map page's settings.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MapConfig {
    /// Leaflet tile URL template (`https://tile.openstreetmap.org/{z}/{x}/{y}.png`); empty:
    /// no tiles, only the embedded outline (the page then makes no request off this daemon).
    pub tile_url: String,
    /// Text shown in the map's corner for the tiles (their licence usually asks for it).
    pub tile_attribution: String,
    /// Deepest zoom level the tile server has.
    pub tile_max_zoom: u8,
    /// Range rings drawn around `[receiver]` when it is set, km.
    pub range_rings_km: Vec<f64>,
}

/// Longest `map.tile_url`, bytes.
const MAX_TILE_URL_BYTES: usize = 2048;
/// Longest `map.tile_attribution`, bytes.
const MAX_ATTRIBUTION_BYTES: usize = 512;
/// Most range rings.
const MAX_RANGE_RINGS: usize = 16;
/// Largest range ring, km: a receiver hears to the radio horizon, ~450 km at 12 km altitude.
const MAX_RANGE_RING_KM: f64 = 2000.0;
/// Placeholders Leaflet fills in a tile URL; any other `{name}` makes it throw at run time.
const TILE_PLACEHOLDERS: &[&str] = &["{s}", "{z}", "{x}", "{y}", "{r}", "{-y}"];

impl MapConfig {
    /// Whether tiles are configured.
    pub fn tiles_on(&self) -> bool {
        !self.tile_url.is_empty()
    }

    pub(super) fn validate(&self) -> Result<(), ConfigError> {
        if self.tiles_on() {
            check_tile_url(&self.tile_url).map_err(|p| bad("map.tile_url", p))?;
        }
        if self.tile_attribution.len() > MAX_ATTRIBUTION_BYTES
            || self.tile_attribution.chars().any(char::is_control)
        {
            return Err(bad(
                "map.tile_attribution",
                format!("must be one line of at most {MAX_ATTRIBUTION_BYTES} bytes"),
            ));
        }
        int_within("map.tile_max_zoom", self.tile_max_zoom, 0, 24)?;
        if self.range_rings_km.len() > MAX_RANGE_RINGS {
            return Err(bad(
                "map.range_rings_km",
                format!("at most {MAX_RANGE_RINGS} rings"),
            ));
        }
        for (i, r) in self.range_rings_km.iter().enumerate() {
            if !(r.is_finite() && *r > 0.0 && *r <= MAX_RANGE_RING_KM) {
                return Err(bad(
                    &format!("map.range_rings_km[{i}]"),
                    format!(
                        "must be within (0, {MAX_RANGE_RING_KM}] km, got {}",
                        Short(*r)
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// An `http(s)://host/...` template holding `{z}`, `{x}` and `{y}`, no other placeholder, and
/// nothing that could leave the string it is placed in (quotes, angle brackets, spaces).
fn check_tile_url(url: &str) -> Result<(), String> {
    if url.len() > MAX_TILE_URL_BYTES {
        return Err(format!("longer than {MAX_TILE_URL_BYTES} bytes"));
    }
    let rest = url
        .strip_prefix("https://")
        .or_else(|| url.strip_prefix("http://"))
        .ok_or_else(|| format!("{url:?}: expected an http:// or https:// URL"))?;
    let host = rest.split('/').next().unwrap_or_default();
    if host.is_empty() {
        return Err(format!("{url:?}: no host"));
    }
    if let Some(c) = url
        .chars()
        .find(|c| c.is_whitespace() || c.is_control() || "\"'<>\\`".contains(*c))
    {
        return Err(format!("{url:?}: {c:?} is not allowed in a URL"));
    }
    for needed in ["{z}", "{x}", "{y}"] {
        if !url.contains(needed) {
            return Err(format!("{url:?}: the template needs {needed}"));
        }
    }
    // Every `{...}` must be one Leaflet knows.
    let mut tail = url;
    while let Some(open) = tail.find('{') {
        let after = &tail[open..];
        let close = after
            .find('}')
            .ok_or_else(|| format!("{url:?}: unclosed {{"))?;
        let name = &after[..=close];
        if !TILE_PLACEHOLDERS.contains(&name) {
            return Err(format!(
                "{url:?}: unknown placeholder {name}; expected {}",
                TILE_PLACEHOLDERS.join(" ")
            ));
        }
        tail = &after[close + 1..];
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::{assert_refused_naming, Config};

    #[test]
    fn tiles_are_off_by_default_and_rings_are_set() {
        let c = Config::default_config().unwrap();
        assert!(!c.map.tiles_on());
        assert_eq!(c.map.tile_max_zoom, 19);
        assert_eq!(c.map.range_rings_km, [50.0, 100.0, 200.0, 300.0]);
    }

    #[test]
    fn a_tile_server_is_accepted() {
        let c = Config::from_toml_str(
            "[map]\ntile_url = \"https://{s}.tile.openstreetmap.org/{z}/{x}/{y}{r}.png\"\n\
             tile_attribution = \"(c) OpenStreetMap contributors\"\n",
        )
        .unwrap();
        assert!(c.map.tiles_on());
    }

    #[test]
    fn bad_map_values_name_their_key() {
        assert_refused_naming(&[
            (
                "[map]\ntile_url = \"tile.osm.org/{z}/{x}/{y}.png\"\n",
                "map.tile_url",
            ),
            (
                "[map]\ntile_url = \"https:///{z}/{x}/{y}.png\"\n",
                "map.tile_url",
            ),
            (
                "[map]\ntile_url = \"https://osm.org/{z}/{x}.png\"\n",
                "map.tile_url",
            ),
            (
                "[map]\ntile_url = \"https://osm.org/{z}/{x}/{y}.png?k={key}\"\n",
                "map.tile_url",
            ),
            (
                "[map]\ntile_url = \"https://osm.org/{z}/{x}/{y}.png\\\"><script>\"\n",
                "map.tile_url",
            ),
            (
                "[map]\ntile_url = \"https://osm.org/{z}/{x}/{y\"\n",
                "map.tile_url",
            ),
            (
                "[map]\ntile_attribution = \"a\\nb\"\n",
                "map.tile_attribution",
            ),
            ("[map]\ntile_max_zoom = 25\n", "map.tile_max_zoom"),
            ("[map]\ntile_max_zoom = -1\n", "tile_max_zoom"),
            (
                "[map]\nrange_rings_km = [100.0, 0.0]\n",
                "map.range_rings_km[1]",
            ),
            ("[map]\nrange_rings_km = [nan]\n", "map.range_rings_km[0]"),
            (
                "[map]\nrange_rings_km = [5000.0]\n",
                "map.range_rings_km[0]",
            ),
        ]);
    }
}
