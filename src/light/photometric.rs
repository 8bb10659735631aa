//! Measured luminaires: IES LM-63 photometric files (type C photometry) read into an intensity
//! table, interpolated bilinearly in the C-gamma angles, and sampled for emission with a
//! piecewise-constant distribution whose pdf is exact.
//!
//! Angles follow LM-63 type C: gamma (the "vertical" angle) is measured from the nadir, the
//! direction the luminaire points to (gamma = 0), to the zenith (180); C (the "horizontal"
//! angle) turns about the nadir axis from the C0 plane (the luminaire's length axis) towards
//! C90. A light built from a profile places the nadir along its `direction` and C0 along its
//! `c0` axis.
//!
//! Why a table of maxima for sampling: the interpolated intensity is bilinear in (gamma, C)
//! between the table's knots, so its largest value over any cell of the sampling grid is found
//! at the cell's corners and the knots inside it. Weighting each cell by that maximum keeps the
//! sampling density positive wherever the intensity is (no light is lost to light tracing) and
//! close to proportional to the intensity on a fine grid.

use std::path::Path;

use crate::error::{Error, Result};
use crate::math::{Distribution2D, Vec2, Vec3, PI};

/// Largest number of vertical or horizontal angles accepted (real files have at most a few
/// hundred; the limit keeps a hostile file from asking for gigabytes).
const MAX_ANGLES: usize = 10_000;
/// Largest number of candela values accepted.
const MAX_VALUES: usize = 1 << 22;
/// Cells of the sampling grid along gamma (uniform in cos gamma, hence in solid angle) and C.
const GRID_GAMMA: usize = 256;
const GRID_C: usize = 256;

/// How a type C table covers the C angles (LM-63's symmetries, told apart by the first and
/// last horizontal angle).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HorizontalSymmetry {
    /// One horizontal angle: the same in every C plane.
    Rotational,
    /// C from 0 to 90: each quadrant mirrors the first.
    Quadrant,
    /// C from 0 to 180: symmetric about the C0-C180 plane.
    Bilateral0To180,
    /// C from 90 to 270: symmetric about the C90-C270 plane.
    Bilateral90To270,
    /// C from 0 to 360 (or to less than 360, wrapping back to C0).
    Full,
}

/// An intensity distribution in candela over the type C angles, with its sampling table.
#[derive(Clone, Debug)]
pub struct PhotometricProfile {
    /// Vertical (gamma) angles in radians, strictly increasing, within [0, pi].
    gamma: Vec<f32>,
    /// Horizontal (C) angles in radians, strictly increasing, as the table gives them.
    c: Vec<f32>,
    symmetry: HorizontalSymmetry,
    /// Candela, `c.len()` rows of `gamma.len()` values.
    candela: Vec<f32>,
    /// Over (x = C / 2 pi, y = (1 - cos gamma) / 2), which is uniform in solid angle.
    distribution: Distribution2D,
    /// Integral of the intensity over the sphere (candela x steradian = lumen), estimated on
    /// the sampling grid.
    flux: f32,
    peak: f32,
}

impl PhotometricProfile {
    /// Reads a photometric file: IES LM-63 (`.ies`, 1986 to 2019 formats) or EULUMDAT
    /// (`.ldt`), told apart by the extension (any other is read as IES). An unreadable file is
    /// an I/O error; malformed content a parse error naming the file and the line.
    pub fn from_file(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let ldt = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("ldt"));
        if ldt {
            Self::parse(&bytes, path, LdtTable::parse)
        } else {
            Self::parse(&bytes, path, IesTable::parse)
        }
    }

    /// Parses IES LM-63 text handed over in memory; errors are parse errors located in
    /// `<memory>`.
    pub fn from_ies_bytes(bytes: &[u8]) -> Result<Self> {
        Self::parse(bytes, Path::new("<memory>"), IesTable::parse)
    }

    /// Parses EULUMDAT text handed over in memory; errors are parse errors located in
    /// `<memory>`.
    pub fn from_ldt_bytes(bytes: &[u8]) -> Result<Self> {
        Self::parse(bytes, Path::new("<memory>"), LdtTable::parse)
    }

    /// Bytes that are not UTF-8 (files are often Latin-1) only matter in text fields, which
    /// are not used.
    fn parse(
        bytes: &[u8],
        path: &Path,
        parser: fn(&str) -> std::result::Result<Table, ParseError>,
    ) -> Result<Self> {
        let text = String::from_utf8_lossy(bytes);
        let table = parser(&text).map_err(|(line, message)| {
            let location = line.map_or(String::new(), |l| format!("line {l}"));
            Error::parse(path, location, message)
        })?;
        Self::from_table(table.gamma_degrees, table.c_degrees, table.candela).map_err(|e| match e {
            Error::InvalidArgument(message) => Error::parse(path, "", message),
            other => other,
        })
    }

    /// A profile from a type C table: `candela` holds one row of `gamma_degrees.len()` values
    /// per horizontal angle. The horizontal range picks the symmetry as LM-63 says.
    pub fn from_table(
        gamma_degrees: Vec<f32>,
        c_degrees: Vec<f32>,
        candela: Vec<f32>,
    ) -> Result<Self> {
        let strictly_increasing = |a: &[f32]| a.windows(2).all(|w| w[0] < w[1]);
        if gamma_degrees.len() < 2 {
            return Err(Error::invalid(format!(
                "{} vertical angles: at least 2 are needed",
                gamma_degrees.len()
            )));
        }
        if c_degrees.is_empty() {
            return Err(Error::invalid("no horizontal angles"));
        }
        if gamma_degrees
            .iter()
            .any(|g| !g.is_finite() || !(0.0..=180.0).contains(g))
            || !strictly_increasing(&gamma_degrees)
        {
            return Err(Error::invalid(
                "vertical angles must increase strictly within [0, 180] degrees",
            ));
        }
        if c_degrees
            .iter()
            .any(|c| !c.is_finite() || !(0.0..=360.0).contains(c))
            || !strictly_increasing(&c_degrees)
        {
            return Err(Error::invalid(
                "horizontal angles must increase strictly within [0, 360] degrees",
            ));
        }
        if candela.len() != gamma_degrees.len() * c_degrees.len() {
            return Err(Error::invalid(format!(
                "{} candela values for {} x {} angles",
                candela.len(),
                c_degrees.len(),
                gamma_degrees.len()
            )));
        }
        if let Some(bad) = candela.iter().find(|v| !v.is_finite() || **v < 0.0) {
            return Err(Error::invalid(format!(
                "candela value {bad} must be finite and >= 0"
            )));
        }
        let (first, last) = (c_degrees[0], c_degrees[c_degrees.len() - 1]);
        let symmetry = if c_degrees.len() == 1 {
            HorizontalSymmetry::Rotational
        } else if first == 0.0 && last == 90.0 {
            HorizontalSymmetry::Quadrant
        } else if first == 0.0 && last == 180.0 {
            HorizontalSymmetry::Bilateral0To180
        } else if first == 90.0 && last == 270.0 {
            HorizontalSymmetry::Bilateral90To270
        } else if first == 0.0 && last > 180.0 {
            HorizontalSymmetry::Full
        } else {
            return Err(Error::invalid(format!(
                "horizontal angles from {first} to {last} degrees match no LM-63 symmetry \
                 (0, 0-90, 0-180, 90-270 or 0-360)"
            )));
        };
        let mut profile = PhotometricProfile {
            gamma: gamma_degrees.iter().map(|g| g.to_radians()).collect(),
            c: c_degrees.iter().map(|c| c.to_radians()).collect(),
            symmetry,
            peak: candela.iter().copied().fold(0.0, f32::max),
            candela,
            distribution: Distribution2D::new(&[1.0], 1, 1),
            flux: 0.0,
        };
        if profile.peak <= 0.0 {
            return Err(Error::invalid("every candela value is zero"));
        }
        profile.build_sampling();
        Ok(profile)
    }

    pub fn symmetry(&self) -> HorizontalSymmetry {
        self.symmetry
    }

    /// Largest tabulated intensity (candela).
    pub fn peak(&self) -> f32 {
        self.peak
    }

    /// Integral of the intensity over all directions (lumen), estimated on the sampling grid.
    pub fn flux(&self) -> f32 {
        self.flux
    }

    /// Intensity (candela) towards `local`, a unit direction in the luminaire's frame: z the
    /// nadir (gamma = 0), x the C0 axis, y the C90 axis.
    pub fn intensity(&self, local: Vec3) -> f32 {
        let gamma = local.z.clamp(-1.0, 1.0).acos();
        let c = local.y.atan2(local.x).rem_euclid(2.0 * PI);
        self.intensity_at(gamma, c)
    }

    /// Intensity at gamma and C in radians (C in [0, 2 pi]).
    pub fn intensity_at(&self, gamma: f32, c: f32) -> f32 {
        let Some((g0, g1, tg)) = bracket(&self.gamma, gamma) else {
            return 0.0;
        };
        let n = self.gamma.len();
        let row = |h: usize| {
            let r = &self.candela[h * n..(h + 1) * n];
            r[g0] * (1.0 - tg) + r[g1] * tg
        };
        if self.symmetry == HorizontalSymmetry::Rotational {
            return row(0);
        }
        let folded = self.fold(c);
        let last = self.c.len() - 1;
        if folded > self.c[last] {
            // A full table ending short of 360 degrees: wrap from its last plane to C0.
            let t = (folded - self.c[last]) / (2.0 * PI - self.c[last]);
            return row(last) * (1.0 - t) + row(0) * t;
        }
        match bracket(&self.c, folded) {
            Some((h0, h1, t)) => row(h0) * (1.0 - t) + row(h1) * t,
            None => 0.0,
        }
    }

    /// Maps C in [0, 2 pi] into the table's horizontal range by its symmetry.
    fn fold(&self, c: f32) -> f32 {
        let half_turn = PI;
        match self.symmetry {
            HorizontalSymmetry::Rotational | HorizontalSymmetry::Full => c,
            HorizontalSymmetry::Quadrant => {
                let c = if c > half_turn { 2.0 * PI - c } else { c };
                if c > 0.5 * PI {
                    PI - c
                } else {
                    c
                }
            }
            HorizontalSymmetry::Bilateral0To180 => {
                if c > half_turn {
                    2.0 * PI - c
                } else {
                    c
                }
            }
            HorizontalSymmetry::Bilateral90To270 => {
                if !(0.5 * PI..=1.5 * PI).contains(&c) {
                    (PI - c).rem_euclid(2.0 * PI)
                } else {
                    c
                }
            }
        }
    }

    /// Every C angle in [0, 2 pi] where the unfolded intensity may have a kink: the table's
    /// knots under every mirror of the symmetry (a superset does no harm).
    fn unfolded_c_knots(&self) -> Vec<f32> {
        let mut knots = vec![0.0, 0.5 * PI, PI, 1.5 * PI, 2.0 * PI];
        for &k in &self.c {
            for v in [k, 2.0 * PI - k, PI - k, PI + k] {
                knots.push(v.rem_euclid(2.0 * PI));
            }
        }
        knots.sort_by(f32::total_cmp);
        knots.dedup();
        knots
    }

    fn build_sampling(&mut self) {
        let width = if self.symmetry == HorizontalSymmetry::Rotational {
            1
        } else {
            GRID_C
        };
        let c_knots = self.unfolded_c_knots();
        let gamma_of = |y: f32| (1.0 - 2.0 * y).clamp(-1.0, 1.0).acos();
        let mut weights = vec![0.0f32; width * GRID_GAMMA];
        let mut flux = 0.0f64;
        let mut gammas = Vec::new();
        let mut cs = Vec::new();
        for iy in 0..GRID_GAMMA {
            let (ga, gb) = (
                gamma_of(iy as f32 / GRID_GAMMA as f32),
                gamma_of((iy + 1) as f32 / GRID_GAMMA as f32),
            );
            gammas.clear();
            gammas.extend([ga, gb]);
            gammas.extend(self.gamma.iter().copied().filter(|&g| g > ga && g < gb));
            for ix in 0..width {
                let (ca, cb) = (
                    2.0 * PI * ix as f32 / width as f32,
                    2.0 * PI * (ix + 1) as f32 / width as f32,
                );
                cs.clear();
                cs.extend([ca, cb]);
                cs.extend(c_knots.iter().copied().filter(|&c| c > ca && c < cb));
                let mut max = 0.0f32;
                for &g in &gammas {
                    for &c in &cs {
                        max = max.max(self.intensity_at(g, c));
                    }
                }
                weights[iy * width + ix] = max;
                let centre = self.intensity_at(0.5 * (ga + gb), 0.5 * (ca + cb));
                flux += centre as f64 * 4.0 * PI as f64 / (width * GRID_GAMMA) as f64;
            }
        }
        self.distribution = Distribution2D::new(&weights, width, GRID_GAMMA);
        self.flux = flux as f32;
    }

    /// Samples a direction in the luminaire's frame roughly proportional to the intensity;
    /// returns it with its solid-angle density.
    pub fn sample_direction(&self, u: Vec2) -> Option<(Vec3, f32)> {
        let (p, pdf) = self.distribution.sample(u);
        if pdf <= 0.0 {
            return None;
        }
        let cos_gamma = 1.0 - 2.0 * p.y;
        let sin_gamma = (1.0 - cos_gamma * cos_gamma).max(0.0).sqrt();
        let (sin_c, cos_c) = (2.0 * PI * p.x).sin_cos();
        let local = Vec3::new(sin_gamma * cos_c, sin_gamma * sin_c, cos_gamma);
        Some((local, pdf / (4.0 * PI)))
    }

    /// Solid-angle density of [`sample_direction`](Self::sample_direction) choosing `local`.
    pub fn direction_pdf(&self, local: Vec3) -> f32 {
        let y = (0.5 * (1.0 - local.z)).clamp(0.0, 1.0);
        let x = (local.y.atan2(local.x) / (2.0 * PI)).rem_euclid(1.0);
        self.distribution.pdf(Vec2::new(x, y)) / (4.0 * PI)
    }

    pub fn memory_bytes(&self) -> usize {
        (self.gamma.len() + self.c.len() + self.candela.len()) * 4
            + self.distribution.memory_bytes()
    }
}

/// A small asymmetric profile (gamma 0-180, C 0-360) for tests elsewhere in the crate.
#[cfg(test)]
pub(crate) fn test_profile() -> PhotometricProfile {
    let gamma: Vec<f32> = (0..=12).map(|i| i as f32 * 15.0).collect();
    let c: Vec<f32> = (0..8).map(|i| i as f32 * 45.0).collect();
    let candela = c
        .iter()
        .flat_map(|&c| {
            gamma.iter().map(move |&g| {
                let (g, c) = (g.to_radians(), c.to_radians());
                (100.0 * g.cos().max(0.0) + 20.0 * (1.0 + c.cos()) * g.sin()).max(0.0)
            })
        })
        .collect();
    PhotometricProfile::from_table(gamma, c, candela).unwrap()
}

/// The knots around `x` in increasing `knots` and the weight of the upper one; `None` outside
/// the knots' range.
fn bracket(knots: &[f32], x: f32) -> Option<(usize, usize, f32)> {
    let (first, last) = (knots[0], knots[knots.len() - 1]);
    if !(first..=last).contains(&x) {
        return None;
    }
    if knots.len() == 1 {
        return Some((0, 0, 0.0));
    }
    let i = knots.partition_point(|&k| k <= x).clamp(1, knots.len() - 1);
    let (a, b) = (knots[i - 1], knots[i]);
    Some((i - 1, i, ((x - a) / (b - a)).clamp(0.0, 1.0)))
}

/// The angles and candela of a photometric file, with its multipliers applied.
struct Table {
    gamma_degrees: Vec<f32>,
    c_degrees: Vec<f32>,
    candela: Vec<f32>,
}

/// IES LM-63 files.
struct IesTable;

/// A parse error: the line (1-based) where it was found, if any, and the message.
type ParseError = (Option<usize>, String);

impl IesTable {
    fn parse(text: &str) -> std::result::Result<Table, ParseError> {
        let mut lines = text.lines().enumerate();
        let (tilt_line, tilt) = loop {
            let Some((i, line)) = lines.next() else {
                return Err((None, "no TILT= line: not an IES LM-63 file".into()));
            };
            if let Some(rest) = line.trim().strip_prefix("TILT=") {
                break (i + 1, rest.trim().to_string());
            }
        };
        let mut numbers = Numbers {
            tokens: lines
                .flat_map(|(i, l)| {
                    l.split(|c: char| c.is_whitespace() || c == ',')
                        .filter(|t| !t.is_empty())
                        .map(move |t| (i + 1, t))
                })
                .collect(),
            next: 0,
            last_line: tilt_line,
        };
        match tilt.as_str() {
            "NONE" => {}
            "INCLUDE" => {
                // Lamp-to-luminaire geometry, then angle and multiplier lists. They describe
                // how output changes when the lamp is tilted in use; Lacuna renders the
                // luminaire as measured and skips them.
                numbers.number("TILT lamp-to-luminaire geometry")?;
                let pairs = numbers.count("TILT angle count", MAX_ANGLES)?;
                for i in 0..2 * pairs {
                    numbers.number(&format!("TILT value {} of {}", i + 1, 2 * pairs))?;
                }
            }
            other => {
                return Err((
                    Some(tilt_line),
                    format!(
                        "TILT={other}: tilt data in a separate file is not supported (use \
                         TILT=NONE or TILT=INCLUDE)"
                    ),
                ))
            }
        }
        let _lamps = numbers.number("number of lamps")?;
        let _lumens_per_lamp = numbers.number("lumens per lamp")?;
        let multiplier = numbers.number("candela multiplier")?;
        let n_gamma = numbers.count("number of vertical angles", MAX_ANGLES)?;
        let n_c = numbers.count("number of horizontal angles", MAX_ANGLES)?;
        let photometric_type = numbers.number("photometric type")?;
        let type_line = numbers.last_line;
        let _units = numbers.number("units type")?;
        for name in ["luminaire width", "luminaire length", "luminaire height"] {
            numbers.number(name)?;
        }
        let ballast = numbers.number("ballast factor")?;
        let ballast_lamp = numbers.number("ballast-lamp photometric factor")?;
        let _watts = numbers.number("input watts")?;
        let at_type = |message: String| Err((Some(type_line), message));
        if photometric_type == 2.0 || photometric_type == 3.0 {
            return at_type(format!(
                "photometric type {photometric_type} (type {}) is not supported: only type C (1), \
                 the type of architectural and road luminaires",
                if photometric_type == 2.0 { "B" } else { "A" }
            ));
        } else if photometric_type != 1.0 {
            return at_type(format!(
                "photometric type {photometric_type} is not 1, 2 or 3"
            ));
        }
        let scale = multiplier * ballast * ballast_lamp;
        if !(scale.is_finite() && scale > 0.0) {
            return at_type(format!(
                "candela multiplier {multiplier} x ballast factor {ballast} x ballast-lamp \
                 factor {ballast_lamp} must be finite and > 0"
            ));
        }
        if n_gamma * n_c > MAX_VALUES {
            return at_type(format!(
                "{n_c} x {n_gamma} candela values exceed the limit of {MAX_VALUES}"
            ));
        }
        let mut list = |n: usize, what: &str| -> std::result::Result<Vec<f32>, ParseError> {
            (0..n)
                .map(|i| numbers.number(&format!("{what} {} of {n}", i + 1)))
                .map(|r| r.map(|v| v as f32))
                .collect()
        };
        let gamma_degrees = list(n_gamma, "vertical angle")?;
        let c_degrees = list(n_c, "horizontal angle")?;
        let mut candela = list(n_gamma * n_c, "candela value")?;
        for v in &mut candela {
            *v = (*v as f64 * scale) as f32;
        }
        Ok(Table {
            gamma_degrees,
            c_degrees,
            candela,
        })
    }
}

/// EULUMDAT files: one value per line, intensities in cd per 1000 lm of lamp flux.
struct LdtTable;

/// The lines of an EULUMDAT file, read in order.
struct LdtLines<'a> {
    lines: Vec<&'a str>,
    at: usize,
}

impl LdtLines<'_> {
    /// The next line, trimmed, with its 1-based number.
    fn text(&mut self, what: &str) -> std::result::Result<(usize, &str), ParseError> {
        let line = self
            .lines
            .get(self.at)
            .map(|l| l.trim())
            .ok_or_else(|| (None, format!("the file ends before the {what}")))?;
        self.at += 1;
        Ok((self.at, line))
    }

    fn number(&mut self, what: &str) -> std::result::Result<f64, ParseError> {
        let (line, text) = self.text(what)?;
        // Some writers use a decimal comma.
        match text.replace(',', ".").parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err((
                Some(line),
                format!("{what} '{text}' is not a finite number"),
            )),
        }
    }
}

impl LdtTable {
    fn parse(text: &str) -> std::result::Result<Table, ParseError> {
        let mut lines = LdtLines {
            lines: text.lines().collect(),
            at: 0,
        };
        let count = |v: f64, line: usize, what: &str, max: usize| {
            if v.fract() != 0.0 || v < 1.0 || v > max as f64 {
                Err((
                    Some(line),
                    format!("{what} {v} must be a whole number from 1 to {max}"),
                ))
            } else {
                Ok(v as usize)
            }
        };
        // Lines 1-3: company, type indicator, symmetry indicator.
        let _ = lines.text("company identification")?;
        let _ = lines.number("type indicator")?;
        let symmetry = lines.number("symmetry indicator")?;
        let symmetry_line = 3;
        let n_c_raw = lines.number("number of C planes")?;
        let n_c = count(n_c_raw, 4, "number of C planes", MAX_ANGLES)?;
        let _ = lines.number("distance between C planes")?;
        let n_g_raw = lines.number("number of gamma angles")?;
        let n_g = count(n_g_raw, 6, "number of gamma angles", MAX_ANGLES)?;
        let _ = lines.number("distance between gamma angles")?;
        // Lines 8-12: report number, luminaire name and number, file name, date and user.
        for what in [
            "measurement report number",
            "luminaire name",
            "luminaire number",
            "file name",
            "date",
        ] {
            lines.text(what)?;
        }
        // Lines 13-25: dimensions, luminous area, downward flux fraction, light output ratio,
        // conversion factor, tilt.
        for what in [
            "luminaire length",
            "luminaire width",
            "luminaire height",
            "luminous area length",
            "luminous area width",
            "luminous area height C0",
            "luminous area height C90",
            "luminous area height C180",
            "luminous area height C270",
            "downward flux fraction",
            "light output ratio",
        ] {
            lines.number(what)?;
        }
        let conversion = lines.number("conversion factor")?;
        let _ = lines.number("tilt")?;
        let sets_raw = lines.number("number of lamp sets")?;
        let sets = count(sets_raw, 26, "number of lamp sets", 20)?;
        // Per set: lamp count, lamp type, total flux, colour temperature, colour rendering,
        // wattage; each field is a block of `sets` lines.
        for _ in 0..sets {
            lines.number("number of lamps")?;
        }
        for _ in 0..sets {
            lines.text("lamp type")?;
        }
        let mut flux = 0.0;
        for _ in 0..sets {
            flux += lines.number("total lamp flux")?;
        }
        for _ in 0..sets {
            lines.text("colour temperature")?;
        }
        for _ in 0..sets {
            lines.text("colour rendering index")?;
        }
        for _ in 0..sets {
            lines.number("wattage")?;
        }
        for _ in 0..10 {
            lines.number("direct ratio")?;
        }
        let c_all = (0..n_c)
            .map(|i| lines.number(&format!("C angle {} of {n_c}", i + 1)))
            .collect::<std::result::Result<Vec<f64>, _>>()?;
        let gamma = (0..n_g)
            .map(|i| lines.number(&format!("gamma angle {} of {n_g}", i + 1)))
            .collect::<std::result::Result<Vec<f64>, _>>()?;
        // The C planes stored, by the symmetry indicator (EN 13032-1): 0 all, 1 one (about the
        // vertical axis), 2 C0 to C180, 3 C90 to C270, 4 C0 to C90.
        let code = if symmetry.fract() == 0.0 && (0.0..=4.0).contains(&symmetry) {
            symmetry as u32
        } else {
            return Err((
                Some(symmetry_line),
                format!("symmetry indicator {symmetry} is not 0, 1, 2, 3 or 4"),
            ));
        };
        let (first, stored) = match code {
            0 => (0, n_c),
            1 => (0, 1),
            2 => (0, n_c / 2 + 1),
            3 => (n_c / 4, n_c / 2 + 1),
            _ => (0, n_c / 4 + 1),
        };
        if first + stored > n_c || n_g * stored > MAX_VALUES {
            return Err((
                Some(4),
                format!("{n_c} C planes do not fit symmetry indicator {symmetry}"),
            ));
        }
        let scale = flux * conversion / 1000.0;
        if !(scale.is_finite() && scale > 0.0) {
            return Err((
                None,
                format!(
                    "total lamp flux {flux} x conversion factor {conversion} must be finite and > 0"
                ),
            ));
        }
        let mut candela = Vec::with_capacity(n_g * stored);
        for plane in 0..stored {
            for i in 0..n_g {
                let v = lines.number(&format!(
                    "intensity {} of {n_g} in stored C plane {}",
                    i + 1,
                    plane + 1
                ))?;
                candela.push((v * scale) as f32);
            }
        }
        let c_degrees = if code == 1 {
            vec![0.0]
        } else {
            c_all[first..first + stored]
                .iter()
                .map(|&c| c as f32)
                .collect()
        };
        Ok(Table {
            gamma_degrees: gamma.iter().map(|&g| g as f32).collect(),
            c_degrees,
            candela,
        })
    }
}

/// The numeric tokens after the TILT line, with their line numbers.
struct Numbers<'a> {
    tokens: Vec<(usize, &'a str)>,
    next: usize,
    /// The line of the last token read (the TILT line before any).
    last_line: usize,
}

impl Numbers<'_> {
    fn number(&mut self, what: &str) -> std::result::Result<f64, ParseError> {
        let Some(&(line, token)) = self.tokens.get(self.next) else {
            return Err((None, format!("the file ends before the {what}")));
        };
        self.next += 1;
        self.last_line = line;
        match token.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err((
                Some(line),
                format!("{what} '{token}' is not a finite number"),
            )),
        }
    }

    fn count(&mut self, what: &str, max: usize) -> std::result::Result<usize, ParseError> {
        let v = self.number(what)?;
        if v.fract() != 0.0 || v < 1.0 || v > max as f64 {
            return Err((
                Some(self.last_line),
                format!("{what} {v} must be a whole number from 1 to {max}"),
            ));
        }
        Ok(v as usize)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{warp, Rng};

    /// A small LM-63-2002 file: a downlight, gamma 0-90, quadrant symmetric.
    const DOWNLIGHT: &str = "IESNA:LM-63-2002
[TEST] unit test
[MANUFAC] Lacuna
TILT=NONE
1 1000 2.0 4 3 1 2 0.1 0.1 0.0
1.0 1.0 20
0 30 60 90
0 45 90
100 80 20 0
100 60 10 0
100 40 5 0
";

    fn profile(text: &str) -> PhotometricProfile {
        PhotometricProfile::from_ies_bytes(text.as_bytes()).unwrap()
    }

    #[test]
    fn the_table_is_read_with_its_multipliers_and_symmetry() {
        let p = profile(DOWNLIGHT);
        assert_eq!(p.symmetry(), HorizontalSymmetry::Quadrant);
        assert_eq!(p.peak(), 200.0);
        // At the knots: gamma 30 in C0, C45, C90, and the mirrors of C45 in every quadrant.
        let at = |g: f32, c: f32| p.intensity_at(g.to_radians(), c.to_radians());
        assert!((at(30.0, 0.0) - 160.0).abs() < 1e-3);
        assert!((at(30.0, 45.0) - 120.0).abs() < 1e-3);
        assert!((at(30.0, 90.0) - 80.0).abs() < 1e-3);
        for c in [135.0, 225.0, 315.0] {
            assert!((at(30.0, c) - 120.0).abs() < 1e-2, "C {c}");
        }
        assert!((at(30.0, 180.0) - 160.0).abs() < 1e-2);
        // Halfway between knots: bilinear.
        assert!((at(15.0, 0.0) - 180.0).abs() < 1e-2);
        // Above the table's last vertical angle the luminaire emits nothing.
        assert_eq!(at(120.0, 0.0), 0.0);
    }

    #[test]
    fn every_symmetry_folds_to_the_same_intensity_as_the_full_table() {
        // A full 0-360 table made from a function with the symmetry, against the reduced one.
        let gamma: Vec<f32> = (0..=18).map(|i| i as f32 * 10.0).collect();
        let f = |g: f32, c: f32| {
            let (g, c) = (g.to_radians(), c.to_radians());
            10.0 + 5.0 * g.cos() + 3.0 * (2.0 * c).cos() * g.sin()
        };
        // f is symmetric under C -> -C and C -> pi - C, so every reduced range describes it.
        let table = |cs: &[f32]| -> PhotometricProfile {
            let values = cs
                .iter()
                .flat_map(|&c| gamma.iter().map(move |&g| f(g, c)))
                .collect();
            PhotometricProfile::from_table(gamma.clone(), cs.to_vec(), values).unwrap()
        };
        let steps =
            |a: i32, b: i32| -> Vec<f32> { (a..=b).step_by(15).map(|c| c as f32).collect() };
        let full = table(&steps(0, 360));
        let cases = [
            (table(&steps(0, 90)), HorizontalSymmetry::Quadrant),
            (table(&steps(0, 180)), HorizontalSymmetry::Bilateral0To180),
            (table(&steps(90, 270)), HorizontalSymmetry::Bilateral90To270),
        ];
        let mut rng = Rng::new(5, 0);
        for (reduced, symmetry) in &cases {
            assert_eq!(reduced.symmetry(), *symmetry);
            for _ in 0..2000 {
                let d = warp::uniform_sphere(rng.uniform2());
                let (a, b) = (full.intensity(d), reduced.intensity(d));
                assert!(
                    (a - b).abs() < 1e-3 * a.max(1.0),
                    "{symmetry:?} {d}: {a} vs {b}"
                );
            }
        }
        let rotational =
            PhotometricProfile::from_table(gamma.clone(), vec![0.0], gamma.clone()).unwrap();
        assert_eq!(rotational.symmetry(), HorizontalSymmetry::Rotational);
        // A full table that stops short of 360 wraps back to C0.
        let short = table(&steps(0, 345));
        assert_eq!(short.symmetry(), HorizontalSymmetry::Full);
        let d = Vec3::new(0.99, -0.1, 0.1).normalize();
        assert!((short.intensity(d) - full.intensity(d)).abs() < 0.05);
    }

    #[test]
    fn the_direction_pdf_integrates_to_one_and_covers_every_lit_direction() {
        let p = profile(DOWNLIGHT);
        let mut rng = Rng::new(9, 0);
        let n = 400_000;
        let (mut integral, mut flux) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let d = warp::uniform_sphere(rng.uniform2());
            let pdf = p.direction_pdf(d);
            let i = p.intensity(d);
            assert!(i == 0.0 || pdf > 0.0, "lit direction {d} has no density");
            integral += pdf as f64 * 4.0 * PI as f64 / n as f64;
            flux += i as f64 * 4.0 * PI as f64 / n as f64;
        }
        assert!((integral - 1.0).abs() < 0.01, "pdf integral {integral}");
        assert!(
            (flux / p.flux() as f64 - 1.0).abs() < 0.02,
            "{flux} vs {}",
            p.flux()
        );
    }

    #[test]
    fn sampled_directions_follow_their_pdf() {
        // Chi-square over a (cos gamma, C) histogram against the pdf integrated per bin.
        let p = profile(DOWNLIGHT);
        let (nz, nc) = (16usize, 16usize);
        let samples = 400_000usize;
        let mut rng = Rng::new(11, 0);
        let mut counts = vec![0.0f64; nz * nc];
        let mut mismatches = 0usize;
        let bin = |d: Vec3| {
            let z = ((0.5 * (1.0 - d.z)) * nz as f32).clamp(0.0, nz as f32 - 1.0) as usize;
            let c = ((d.y.atan2(d.x) / (2.0 * PI)).rem_euclid(1.0) * nc as f32) as usize;
            z * nc + c.min(nc - 1)
        };
        for _ in 0..samples {
            let (d, pdf) = p.sample_direction(rng.uniform2()).unwrap();
            assert!((d.length() - 1.0).abs() < 1e-4);
            // The pdf of the direction read back agrees, but for directions that round into
            // a neighbouring cell of the sampling grid.
            let expected = p.direction_pdf(d);
            if (pdf - expected).abs() > 1e-3 * expected {
                mismatches += 1;
            }
            counts[bin(d)] += 1.0;
        }
        assert!(mismatches * 1000 < samples, "{mismatches} pdf mismatches");
        // Expected counts by integrating the pdf per bin on a fine grid.
        let fine = 64usize;
        let mut expected = vec![0.0f64; nz * nc];
        for iz in 0..nz * fine {
            for ic in 0..nc * fine {
                let y = (iz as f32 + 0.5) / (nz * fine) as f32;
                let x = (ic as f32 + 0.5) / (nc * fine) as f32;
                let cos_g = 1.0 - 2.0 * y;
                let sin_g = (1.0 - cos_g * cos_g).sqrt();
                let (s, c) = (2.0 * PI * x).sin_cos();
                let d = Vec3::new(sin_g * c, sin_g * s, cos_g);
                let area = 4.0 * PI as f64 / (nz * nc * fine * fine) as f64;
                expected[bin(d)] += p.direction_pdf(d) as f64 * area * samples as f64;
            }
        }
        let (mut chi2, mut dof) = (0.0, 0);
        for (o, e) in counts.iter().zip(&expected) {
            if *e >= 5.0 {
                chi2 += (o - e) * (o - e) / e;
                dof += 1;
            } else {
                assert!(*o <= 20.0, "samples where the pdf expects none");
            }
        }
        // dof ~ 100-250: a 1e-4 quantile is about dof + 4.3 sqrt(2 dof) + 10.
        let limit = dof as f64 + 4.3 * (2.0 * dof as f64).sqrt() + 10.0;
        assert!(chi2 < limit, "chi2 {chi2} over {dof} bins (limit {limit})");
    }

    /// An EULUMDAT file of f (cd per 1000 lm, lamp flux 2000 lm) over 24 C planes and gamma
    /// 0-180 in 10 degree steps, storing the planes `symmetry` says.
    fn ldt(symmetry: u32, f: impl Fn(f32, f32) -> f32) -> String {
        let mut lines: Vec<String> = vec!["Lacuna test".into(), "1".into(), symmetry.to_string()];
        lines.extend(["24", "15", "19", "10"].map(String::from));
        lines.extend(["report", "luminaire", "LAC-1", "test.ldt", "2026-12-05"].map(String::from));
        lines.extend(["100", "100", "50", "90", "90", "0", "0", "0", "0"].map(String::from));
        lines.extend(
            [
                "100", "85,5", "1.0", "0", "1", "1", "LED", "2000", "3000", "80", "12",
            ]
            .map(String::from),
        );
        lines.extend((0..10).map(|i| format!("0.{}", 5 + i % 5)));
        lines.extend((0..24).map(|i| (i * 15).to_string()));
        lines.extend((0..19).map(|i| (i * 10).to_string()));
        let planes: Vec<usize> = match symmetry {
            0 => (0..24).collect(),
            1 => vec![0],
            2 => (0..13).collect(),
            3 => (6..19).collect(),
            _ => (0..7).collect(),
        };
        for p in planes {
            for g in 0..19 {
                lines.push(format!("{}", f((g * 10) as f32, (p * 15) as f32)));
            }
        }
        lines.join("\r\n")
    }

    #[test]
    fn eulumdat_files_give_the_same_profile_for_every_symmetry() {
        let f = |g: f32, c: f32| {
            let (g, c) = (g.to_radians(), c.to_radians());
            10.0 + 5.0 * g.cos() + 3.0 * (2.0 * c).cos() * g.sin()
        };
        let gamma: Vec<f32> = (0..19).map(|i| i as f32 * 10.0).collect();
        let cs: Vec<f32> = (0..=24).map(|i| i as f32 * 15.0).collect();
        let values = cs
            .iter()
            .flat_map(|&c| gamma.iter().map(move |&g| 2.0 * f(g, c)))
            .collect();
        let full = PhotometricProfile::from_table(gamma, cs, values).unwrap();
        let mut rng = Rng::new(8, 0);
        for (symmetry, expected) in [
            (0, HorizontalSymmetry::Full),
            (2, HorizontalSymmetry::Bilateral0To180),
            (3, HorizontalSymmetry::Bilateral90To270),
            (4, HorizontalSymmetry::Quadrant),
        ] {
            let p = PhotometricProfile::from_ldt_bytes(ldt(symmetry, f).as_bytes()).unwrap();
            assert_eq!(p.symmetry(), expected);
            for _ in 0..1000 {
                let d = warp::uniform_sphere(rng.uniform2());
                let (a, b) = (full.intensity(d), p.intensity(d));
                assert!((a - b).abs() < 1e-3 * a, "Isym {symmetry} {d}: {a} vs {b}");
            }
        }
        let round = PhotometricProfile::from_ldt_bytes(ldt(1, |g, _| 100.0 - g / 2.0).as_bytes());
        let round = round.unwrap();
        assert_eq!(round.symmetry(), HorizontalSymmetry::Rotational);
        assert_eq!(round.peak(), 200.0);
        // Errors: a bad symmetry indicator, a truncated table, a missing lamp flux.
        let error = |text: String| {
            PhotometricProfile::from_ldt_bytes(text.as_bytes())
                .unwrap_err()
                .to_string()
        };
        let text = ldt(4, f);
        assert!(error(text.replacen("\r\n4\r\n", "\r\n7\r\n", 1)).contains("symmetry indicator 7"));
        let cut = text.rfind("\r\n").unwrap();
        assert!(error(text[..cut].to_string()).contains("ends before the intensity 19 of 19"));
        assert!(error(text.replacen("\r\n2000\r\n", "\r\nx\r\n", 1)).contains("line 29"));
    }

    #[test]
    fn bad_and_truncated_files_get_clear_errors() {
        let error = |text: &str| {
            PhotometricProfile::from_ies_bytes(text.as_bytes())
                .unwrap_err()
                .to_string()
        };
        assert!(error("hello").contains("TILT"));
        assert!(error(&DOWNLIGHT.replace("TILT=NONE", "TILT=lamp.tlt")).contains("separate file"));
        let cut = &DOWNLIGHT[..DOWNLIGHT.len() - 12];
        assert!(
            error(cut).contains("ends before the candela value"),
            "{}",
            error(cut)
        );
        assert!(error(&DOWNLIGHT.replace("4 3 1 2", "4 3 2 2")).contains("type B"));
        assert!(error(&DOWNLIGHT.replace("4 3 1 2", "4 3 3 2")).contains("type A"));
        assert!(error(&DOWNLIGHT.replace("0 30 60 90", "0 60 30 90")).contains("increase"));
        assert!(error(&DOWNLIGHT.replace("100 80 20 0", "100 -80 20 0")).contains(">= 0"));
        assert!(error(&DOWNLIGHT.replace("100 80 20 0", "100 nan 20 0")).contains("finite"));
        assert!(error(&DOWNLIGHT.replace("4 3 1 2", "4e9 3 1 2")).contains("whole number"));
        assert!(error(&DOWNLIGHT.replace("0 45 90", "0 45 100")).contains("symmetry"));
        assert!(error(&DOWNLIGHT.replace("2.0 4 3", "0 4 3")).contains("> 0"));
        let dark = DOWNLIGHT
            .replace("100 80 20 0", "0 0 0 0")
            .replace("100 60 10 0", "0 0 0 0")
            .replace("100 40 5 0", "0 0 0 0");
        assert!(error(&dark).contains("zero"));
        // TILT=INCLUDE data is read and skipped; a truncated one is an error.
        let tilted = DOWNLIGHT.replace("TILT=NONE", "TILT=INCLUDE\n1\n3\n0 45 90\n1.0 0.9 0.8");
        assert_eq!(profile(&tilted).peak(), 200.0);
        let short_tilt = DOWNLIGHT.replace("TILT=NONE", "TILT=INCLUDE\n1\n3000\n0 45 90");
        assert!(!error(&short_tilt).is_empty());
    }

    #[test]
    fn arbitrary_bytes_never_panic() {
        let mut rng = Rng::new(21, 0);
        let eulumdat = ldt(0, |g, c| 1.0 + g + c);
        for _ in 0..2000 {
            for (base, parse) in [
                (
                    DOWNLIGHT.as_bytes(),
                    PhotometricProfile::from_ies_bytes as fn(&[u8]) -> _,
                ),
                (eulumdat.as_bytes(), PhotometricProfile::from_ldt_bytes),
            ] {
                let mut bytes = base.to_vec();
                let cut = (rng.uniform() * bytes.len() as f32) as usize;
                bytes.truncate(cut.max(1));
                for _ in 0..3 {
                    let i = (rng.uniform() * bytes.len() as f32) as usize % bytes.len();
                    bytes[i] = (rng.uniform() * 256.0) as u8;
                }
                let _ = parse(&bytes);
            }
        }
    }
}
