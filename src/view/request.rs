//! Reading the viewer's requests: fixed routes, query parameters checked
//! one by one. A bad request is a [`Refusal`] (a status and a message),
//! never a panic; sizes are capped so that no request costs more than one
//! bounded frame.

use glam::DVec3;

/// Largest frame side served, in pixels.
pub const MAX_SIDE: u32 = 1024;
/// Most pixels of one frame (1024², about 0.1 s of a few hundred
/// primitives on 2 cores).
pub const MAX_PIXELS: u32 = 1024 * 1024;
/// Longest request target accepted (a frame's is about 150 bytes).
pub const MAX_URL: usize = 2048;
/// Coordinates beyond this are refused (f32 tracing resolves nothing there).
pub const MAX_COORD: f64 = 1e6;
/// Focal lengths (NDC units) accepted: about 180° down to 1°.
pub const FOCAL_RANGE: (f64, f64) = (0.01, 100.0);

/// Why a request was not served: the HTTP status and a message for the page.
#[derive(Debug, Clone, PartialEq)]
pub struct Refusal {
    /// 400, 404, 405, 414…
    pub status: u16,
    /// Said in the response body.
    pub message: String,
}

impl Refusal {
    /// A malformed request (400).
    pub fn bad(message: impl Into<String>) -> Refusal {
        Refusal {
            status: 400,
            message: message.into(),
        }
    }
    /// Something the program does not have (404).
    pub fn missing(message: impl Into<String>) -> Refusal {
        Refusal {
            status: 404,
            message: message.into(),
        }
    }
}

/// The routes the viewer serves; anything else is 404.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Route {
    /// The page.
    Page,
    /// The counter bumped at each reload, and the file's diagnostics.
    Version,
    /// The program's scenes (its `render` statements) and their cameras.
    Scenes,
    /// One frame of a scene, as PNG.
    Frame,
    /// One frame of a trained field at its latest checkpoint, as PNG.
    Field,
    /// The training runs' metrics.
    Train,
    /// A training run's current held-out view beside its truth, as PNG.
    HeldOut,
}

impl Route {
    /// The route of a path (the part before `?`).
    pub fn of(path: &str) -> Option<Route> {
        Some(match path {
            "/" | "/index.html" => Route::Page,
            "/api/version" => Route::Version,
            "/api/scenes" => Route::Scenes,
            "/api/frame" => Route::Frame,
            "/api/field" => Route::Field,
            "/api/train" => Route::Train,
            "/api/heldout" => Route::HeldOut,
            _ => return None,
        })
    }
}

/// A request target split into its route and decoded query parameters.
pub struct Target {
    /// Which route.
    pub route: Route,
    params: Vec<(String, String)>,
}

impl Target {
    /// Parses `/path?a=1&b=2`; unknown paths are 404, over-long or
    /// undecodable targets 400 or 414.
    pub fn parse(url: &str) -> Result<Target, Refusal> {
        if url.len() > MAX_URL {
            return Err(Refusal {
                status: 414,
                message: format!("the request is longer than {MAX_URL} bytes"),
            });
        }
        let (path, query) = url.split_once('?').unwrap_or((url, ""));
        let route =
            Route::of(path).ok_or_else(|| Refusal::missing(format!("no such page: {path}")))?;
        let mut params = Vec::new();
        for pair in query.split('&').filter(|p| !p.is_empty()) {
            let (k, v) = pair.split_once('=').unwrap_or((pair, ""));
            params.push((decode(k)?, decode(v)?));
        }
        Ok(Target { route, params })
    }

    /// The value of parameter `name`, if given (the last, if repeated).
    pub fn get(&self, name: &str) -> Option<&str> {
        self.params
            .iter()
            .rev()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }

    /// A required parameter.
    pub fn require(&self, name: &str) -> Result<&str, Refusal> {
        self.get(name)
            .ok_or_else(|| Refusal::bad(format!("`{name}` is missing")))
    }
}

/// Percent-decoding (`%2C` → `,`, `+` → space), as UTF-8.
fn decode(s: &str) -> Result<String, Refusal> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'%' => {
                let hex = bytes
                    .get(i + 1..i + 3)
                    .and_then(|h| std::str::from_utf8(h).ok())
                    .and_then(|h| u8::from_str_radix(h, 16).ok())
                    .ok_or_else(|| Refusal::bad("a `%` not followed by two hex digits"))?;
                out.push(hex);
                i += 3;
            }
            b'+' => {
                out.push(b' ');
                i += 1;
            }
            b => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).map_err(|_| Refusal::bad("a parameter is not UTF-8"))
}

/// A finite number of at most [`MAX_COORD`] in magnitude.
fn number(name: &str, s: &str) -> Result<f64, Refusal> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| Refusal::bad(format!("`{name}`: `{s}` is not a number")))?;
    if !v.is_finite() || v.abs() > MAX_COORD {
        return Err(Refusal::bad(format!(
            "`{name}`: {s} is not a finite number within ±{MAX_COORD:e}"
        )));
    }
    Ok(v)
}

/// `x,y,z`.
pub fn vec3(name: &str, s: &str) -> Result<DVec3, Refusal> {
    let parts: Vec<&str> = s.split(',').collect();
    let [x, y, z] = parts[..] else {
        return Err(Refusal::bad(format!(
            "`{name}`: expected three numbers x,y,z, got `{s}`"
        )));
    };
    Ok(DVec3::new(
        number(name, x)?,
        number(name, y)?,
        number(name, z)?,
    ))
}

/// `WxH`, each side 1..=[`MAX_SIDE`], at most [`MAX_PIXELS`].
pub fn size(s: &str) -> Result<(u32, u32), Refusal> {
    let bad = || {
        Refusal::bad(format!(
            "`size`: expected WIDTHxHEIGHT (each 1 to {MAX_SIDE}), got `{s}`"
        ))
    };
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: u32 = w.trim().parse().map_err(|_| bad())?;
    let h: u32 = h.trim().parse().map_err(|_| bad())?;
    if w == 0 || h == 0 || w > MAX_SIDE || h > MAX_SIDE || w * h > MAX_PIXELS {
        return Err(bad());
    }
    Ok((w, h))
}

/// A focal length in NDC units within [`FOCAL_RANGE`].
pub fn focal(s: &str) -> Result<f64, Refusal> {
    let f = number("focal", s)?;
    let (lo, hi) = FOCAL_RANGE;
    if !(lo..=hi).contains(&f) {
        return Err(Refusal::bad(format!("`focal`: {f} is outside {lo}..={hi}")));
    }
    Ok(f)
}

/// A statement name: what `sdfl` names statements (letters, digits, `_`),
/// looked up in the program, never used as a path as given.
pub fn name<'a>(what: &str, s: &'a str) -> Result<&'a str, Refusal> {
    let ok =
        !s.is_empty() && s.len() <= 255 && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    if ok {
        Ok(s)
    } else {
        Err(Refusal::bad(format!(
            "`{what}`: `{s}` is not a statement name"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_split_into_routes_and_decoded_parameters() {
        let t = Target::parse("/api/frame?scene=a_1&eye=1%2C2,3&x=a+b").unwrap();
        assert_eq!(t.route, Route::Frame);
        assert_eq!(t.get("scene"), Some("a_1"));
        assert_eq!(t.get("eye"), Some("1,2,3"));
        assert_eq!(t.get("x"), Some("a b"));
        assert_eq!(t.get("none"), None);
        assert_eq!(Target::parse("/").unwrap().route, Route::Page);
    }

    #[test]
    fn hostile_targets_are_refused_not_panicked_on() {
        assert_eq!(Target::parse("/../etc/passwd").err().unwrap().status, 404);
        assert_eq!(Target::parse("/api/frame/../x").err().unwrap().status, 404);
        assert_eq!(Target::parse("/api/frame?a=%").err().unwrap().status, 400);
        assert_eq!(Target::parse("/api/frame?a=%zz").err().unwrap().status, 400);
        assert_eq!(Target::parse("/api/frame?a=%ff").err().unwrap().status, 400);
        // A multi-byte character where hex digits belong.
        assert_eq!(Target::parse("/api/frame?a=%é").err().unwrap().status, 400);
        let long = format!("/api/frame?a={}", "x".repeat(MAX_URL));
        assert_eq!(Target::parse(&long).err().unwrap().status, 414);
    }

    #[test]
    fn numbers_sizes_and_names_are_checked() {
        assert_eq!(vec3("eye", "1,-2,3.5").unwrap(), DVec3::new(1.0, -2.0, 3.5));
        for bad in [
            "1,2", "1,2,3,4", "1,nan,3", "1,inf,3", "1,2,1e7", "", "a,b,c",
        ] {
            assert_eq!(vec3("eye", bad).err().unwrap().status, 400, "{bad}");
        }
        assert_eq!(size("256x128").unwrap(), (256, 128));
        for bad in [
            "0x10",
            "10x0",
            "1025x2",
            "99999999999x1",
            "4096x4096",
            "10",
            "-1x5",
            "axb",
        ] {
            assert!(size(bad).is_err(), "{bad}");
        }
        assert!(focal("1.5").is_ok());
        for bad in ["0", "-1", "1e9", "nan"] {
            assert!(focal(bad).is_err(), "{bad}");
        }
        assert!(name("scene", "large_scene").is_ok());
        for bad in ["", "../x", "a/b", "a.png", "a b"] {
            assert!(name("scene", bad).is_err(), "{bad}");
        }
    }
}
