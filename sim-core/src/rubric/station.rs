//! Station and rubric definitions: the authored, versioned data under `assets/stations/`.
//!
//! Everything here is parsed once and validated once ([`Station::from_toml_str`] does both), so a
//! station that reaches the engine or the server has positive weights, unique ids, coherent
//! tolerances and a revision.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The name of a modality a station uses: lower-case snake case, 1 to
/// [`Modality::MAX_CHARS`] characters. The names are open: which ones a render worker can run is
/// decided by the modalities registered with it (the worker's modality factory), and a session
/// whose station lists a modality its worker lacks says so. The workspace's own are
/// [`Modality::FLUOROSCOPY`] (the C-arm), [`Modality::ULTRASOUND`] (B-mode) and
/// [`Modality::CONTRAST`] (contrast and saline injected through the needle, transported in the
/// spinal compartments by `sim_core::contrast` and seen on fluoroscopy; a station without it
/// builds no transport model).
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct Modality(String);

impl Modality {
    /// X-ray fluoroscopy.
    pub const FLUOROSCOPY: &'static str = "fluoroscopy";
    /// B-mode ultrasound.
    pub const ULTRASOUND: &'static str = "ultrasound";
    /// Contrast transport.
    pub const CONTRAST: &'static str = "contrast";
    /// Longest name, characters. Simulator choice: names are single words or short phrases.
    pub const MAX_CHARS: usize = 32;

    /// A modality name, checked.
    pub fn new(name: &str) -> Result<Modality, ModalityNameError> {
        let ok = !name.is_empty()
            && name.len() <= Modality::MAX_CHARS
            && name.starts_with(|c: char| c.is_ascii_lowercase())
            && name
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_');
        if ok {
            Ok(Modality(name.to_string()))
        } else {
            Err(ModalityNameError(name.to_string()))
        }
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

/// A modality name that is not lower-case snake case of 1 to [`Modality::MAX_CHARS`] characters.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("modality {0:?} must be lower-case snake case, 1 to 32 characters")]
pub struct ModalityNameError(pub String);

impl TryFrom<String> for Modality {
    type Error = ModalityNameError;
    fn try_from(s: String) -> Result<Modality, ModalityNameError> {
        Modality::new(&s)
    }
}

impl From<Modality> for String {
    fn from(m: Modality) -> String {
        m.0
    }
}

impl std::fmt::Display for Modality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl PartialEq<str> for Modality {
    fn eq(&self, other: &str) -> bool {
        self.0 == other
    }
}

/// The unit of a criterion's measurement. The measurement key must end in `_<unit>` (for example
/// `tip_to_target_mm`), so the unit travels with every value that the server stores.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Unit {
    /// Millimetres.
    Mm,
    /// Degrees of angle.
    Deg,
    /// A count of events (images acquired, needle passes).
    Count,
    /// Seconds.
    S,
    /// A dimensionless fraction in 0..=1.
    Fraction,
    /// A yes/no observation, stored as 1.0 (yes) or 0.0 (no).
    Bool,
    /// Milligray (air kerma).
    Mgy,
    /// Gray square centimetres (kerma-area product).
    Gycm2,
}

impl Unit {
    /// The unit's suffix as used in measurement keys and displayed to people.
    pub fn name(self) -> &'static str {
        match self {
            Unit::Mm => "mm",
            Unit::Deg => "deg",
            Unit::Count => "count",
            Unit::S => "s",
            Unit::Fraction => "fraction",
            Unit::Bool => "bool",
            Unit::Mgy => "mgy",
            Unit::Gycm2 => "gycm2",
        }
    }
}

/// How a measured value earns credit in 0..=1.
///
/// The laws are piecewise linear: full credit on the good side of one bound, zero credit beyond
/// the other, and a straight line in between. When the two bounds are equal the law is a step and
/// the value at the bound earns full credit. Values exactly on a bound belong to the better side.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "law", rename_all = "snake_case", deny_unknown_fields)]
pub enum Tolerance {
    /// For errors and distances: credit 1 when `value <= pass_within`, 0 when
    /// `value >= fail_beyond`, and `(fail_beyond - value) / (fail_beyond - pass_within)` between.
    LowerIsBetter {
        /// Largest value that still earns full credit.
        pass_within: f64,
        /// Value from which the credit is zero.
        fail_beyond: f64,
    },
    /// For quantities with an ideal value (a view angle): [`Tolerance::LowerIsBetter`] applied to
    /// the deviation `|measured - value|`.
    NearValue {
        /// The ideal value.
        value: f64,
        /// Largest deviation that still earns full credit.
        pass_within: f64,
        /// Deviation from which the credit is zero.
        fail_beyond: f64,
    },
    /// For quantities where more is better: credit 1 when `value >= pass_from`, 0 when
    /// `value <= fail_below`, and `(value - fail_below) / (pass_from - fail_below)` between.
    HigherIsBetter {
        /// Smallest value that earns full credit.
        pass_from: f64,
        /// Value at and below which the credit is zero.
        fail_below: f64,
    },
    /// For yes/no observations (measurement 1.0 = yes, 0.0 = no): credit 1 when the observation
    /// equals `expected`, else 0. Any other value is an unusable measurement, not a zero.
    Boolean {
        /// The observation that earns credit.
        expected: bool,
    },
}

/// A measured value a tolerance cannot score.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Unscorable {
    /// NaN or infinite.
    #[error("measured value {0} is not a finite number")]
    NotFinite(f64),
    /// A yes/no measurement other than 1 or 0.
    #[error("yes/no measurement must be 1 or 0, got {0}")]
    NotBoolean(f64),
}

impl Tolerance {
    /// Credit in 0..=1 for a measured value, or why the value cannot be scored.
    pub fn credit(&self, value: f64) -> Result<f64, Unscorable> {
        if !value.is_finite() {
            return Err(Unscorable::NotFinite(value));
        }
        let lower_is_better = |v: f64, pass_within: f64, fail_beyond: f64| {
            if v <= pass_within {
                1.0
            } else if v >= fail_beyond {
                0.0
            } else {
                (fail_beyond - v) / (fail_beyond - pass_within)
            }
        };
        Ok(match *self {
            Tolerance::LowerIsBetter {
                pass_within,
                fail_beyond,
            } => lower_is_better(value, pass_within, fail_beyond),
            Tolerance::NearValue {
                value: ideal,
                pass_within,
                fail_beyond,
            } => lower_is_better((value - ideal).abs(), pass_within, fail_beyond),
            Tolerance::HigherIsBetter {
                pass_from,
                fail_below,
            } => {
                if value >= pass_from {
                    1.0
                } else if value <= fail_below {
                    0.0
                } else {
                    (value - fail_below) / (pass_from - fail_below)
                }
            }
            Tolerance::Boolean { expected } => {
                let observed = if value == 1.0 {
                    true
                } else if value == 0.0 {
                    false
                } else {
                    return Err(Unscorable::NotBoolean(value));
                };
                if observed == expected { 1.0 } else { 0.0 }
            }
        })
    }

    fn problems(&self) -> Vec<String> {
        let mut out = Vec::new();
        let finite = |name: &str, v: f64, out: &mut Vec<String>| {
            if !v.is_finite() {
                out.push(format!("tolerance {name} = {v} is not finite"));
            }
        };
        match *self {
            Tolerance::LowerIsBetter {
                pass_within,
                fail_beyond,
            } => {
                finite("pass_within", pass_within, &mut out);
                finite("fail_beyond", fail_beyond, &mut out);
                if pass_within > fail_beyond {
                    out.push(format!(
                        "tolerance pass_within ({pass_within}) exceeds fail_beyond ({fail_beyond})"
                    ));
                }
            }
            Tolerance::NearValue {
                value,
                pass_within,
                fail_beyond,
            } => {
                finite("value", value, &mut out);
                finite("pass_within", pass_within, &mut out);
                finite("fail_beyond", fail_beyond, &mut out);
                if pass_within < 0.0 {
                    out.push(format!("tolerance pass_within ({pass_within}) is negative"));
                }
                if pass_within > fail_beyond {
                    out.push(format!(
                        "tolerance pass_within ({pass_within}) exceeds fail_beyond ({fail_beyond})"
                    ));
                }
            }
            Tolerance::HigherIsBetter {
                pass_from,
                fail_below,
            } => {
                finite("pass_from", pass_from, &mut out);
                finite("fail_below", fail_below, &mut out);
                if fail_below > pass_from {
                    out.push(format!(
                        "tolerance fail_below ({fail_below}) exceeds pass_from ({pass_from})"
                    ));
                }
            }
            Tolerance::Boolean { .. } => {}
        }
        out
    }
}

/// One scored item of a rubric.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Criterion {
    /// Identifier, unique within the rubric (`[a-z0-9_]+`).
    pub id: String,
    /// What the criterion checks, in words shown to learners and faculty.
    pub description: String,
    /// Key of the measurement the criterion reads; ends in `_<unit>`.
    pub measurement: String,
    /// Unit of the measurement.
    pub unit: Unit,
    /// Relative weight in the aggregate score; positive and finite.
    pub weight: f64,
    /// A measured failure of a critical criterion makes the whole result "not met".
    #[serde(default)]
    pub critical: bool,
    /// The station target the measurement refers to, if any (must name one of the targets).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<String>,
    /// How a measured value earns credit.
    pub tolerance: Tolerance,
}

impl Criterion {
    /// True when a critical criterion's credit counts as a failure: a credit of zero, i.e. the
    /// value lies at or beyond the tolerance's zero-credit bound (or a yes/no observation is the
    /// wrong one). Partial credit on a critical criterion is scored, not a failure; authors who want
    /// a hard limit set both bounds equal.
    pub fn is_failure(credit: f64) -> bool {
        credit <= 0.0
    }
}

/// A rubric: weighted criteria and a pass threshold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rubric {
    /// Revision of the rubric, at least 1; bumped whenever criteria, weights or tolerances change,
    /// so stored results say exactly which rules produced them.
    pub revision: u32,
    /// Smallest weighted score (0..=1) that is "met" when every measurement is present.
    pub pass_threshold: f64,
    /// The criteria, in display order.
    pub criteria: Vec<Criterion>,
}

/// An instrument offered at a station.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Instrument {
    /// Identifier, unique within the station.
    pub id: String,
    /// Kind of instrument, e.g. `tuohy-needle`, `spinal-needle`, `contrast-syringe`.
    pub kind: String,
    /// Needle gauge (Birmingham/Stubs), if a needle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gauge: Option<u32>,
    /// Usable length in millimetres, if a needle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub length_mm: Option<f64>,
    /// Free-text note.
    #[serde(default)]
    pub description: String,
}

/// A named landmark in the region's model frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Target {
    /// Identifier, unique within the station (`[a-z0-9_]+`).
    pub name: String,
    /// Position in millimetres in the station's frame (see `frame_note`); for a target that
    /// names a [`Target::landmark`], the fallback used on regions that do not publish it.
    pub position_mm: [f64; 3],
    /// A landmark of the region (computed from its anatomy, such as the phantom's
    /// `L4_L5_posterior_epidural_space`) that this target is: where the region publishes it, the
    /// target is the landmark's position.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub landmark: Option<String>,
    /// What the landmark is.
    #[serde(default)]
    pub description: String,
}

/// A training station: region, modalities, instruments, targets and rubric.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Station {
    /// Identifier (`[a-z0-9-]+`), equal to the file stem under `assets/stations/`.
    pub id: String,
    /// Revision of the station (targets, instruments, region), at least 1.
    pub revision: u32,
    /// Short human title.
    pub title: String,
    /// Longer description of the task.
    #[serde(default)]
    pub description: String,
    /// Anatomy region asset the station runs in (a folder name under `assets/`).
    pub region: String,
    /// How the target coordinates relate to the region's frame, in words.
    #[serde(default)]
    pub frame_note: String,
    /// Imaging modalities, at least one.
    pub modalities: Vec<Modality>,
    /// The C-arm's image receptor (`"flat_panel"` or `"image_intensifier"`, see
    /// [`crate::fluoro::receptor`]); a flat panel when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector: Option<crate::fluoro::receptor::ReceptorKind>,
    /// The patient's body habitus (`"slim"`, `"average"` or `"obese"`, see
    /// [`crate::anatomy::phantom::habitus`]); only for the procedural lumbar phantom, whose
    /// variant it selects. Average when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub habitus: Option<crate::anatomy::phantom::habitus::Habitus>,
    /// Instruments on the tray.
    #[serde(default)]
    pub instruments: Vec<Instrument>,
    /// Named targets.
    #[serde(default)]
    pub targets: Vec<Target>,
    /// The rubric that scores an attempt.
    pub rubric: Rubric,
}

/// A station file as loaded from disk, with its text (so callers can hash it).
#[derive(Debug, Clone)]
pub struct StationFile {
    /// Where it was read from.
    pub path: PathBuf,
    /// The exact file contents.
    pub text: String,
    /// The parsed, validated station.
    pub station: Station,
}

/// Why a station could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum StationError {
    /// The file or directory could not be read.
    #[error("cannot read {path}: {message}")]
    Io {
        /// The path.
        path: String,
        /// The operating system's message.
        message: String,
    },
    /// The text is not a well-formed station (syntax, missing or unknown fields, wrong types).
    #[error("cannot parse station{}: {message}", path_suffix(.path))]
    Parse {
        /// The file, when parsing from disk.
        path: Option<String>,
        /// The parser's message.
        message: String,
    },
    /// The station parsed but breaks a rule (listed in full).
    #[error("station {station:?} is invalid: {}", .problems.join("; "))]
    Invalid {
        /// Station id (or file name).
        station: String,
        /// Every rule it breaks.
        problems: Vec<String>,
    },
}

fn path_suffix(path: &Option<String>) -> String {
    path.as_ref().map(|p| format!(" {p}")).unwrap_or_default()
}

fn is_slug(s: &str, sep: char) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == sep)
        && !s.starts_with(sep)
        && !s.ends_with(sep)
}

impl Station {
    /// The region asset this station runs in: `region`, or the lumbar phantom's variant for the
    /// station's habitus.
    pub fn region_asset(&self) -> String {
        match self.habitus {
            Some(h) if self.region == crate::anatomy::phantom::REGION_NAME => h.region_name(),
            _ => self.region.clone(),
        }
    }

    /// Parse a station from TOML and validate it.
    pub fn from_toml_str(text: &str) -> Result<Station, StationError> {
        let station: Station = toml::from_str(text).map_err(|e| StationError::Parse {
            path: None,
            message: e.to_string(),
        })?;
        station.validate()?;
        Ok(station)
    }

    /// Every rule the station breaks; empty when it is valid.
    pub fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        if !is_slug(&self.id, '-') {
            p.push(format!(
                "station id {:?} must be lowercase letters, digits and '-'",
                self.id
            ));
        }
        if self.revision == 0 {
            p.push("station revision must be at least 1".to_string());
        }
        if self.title.trim().is_empty() {
            p.push("title is empty".to_string());
        }
        if !is_slug(&self.region, '-') {
            p.push(format!(
                "region {:?} must be lowercase letters, digits and '-'",
                self.region
            ));
        }
        if self.habitus.is_some() && self.region != crate::anatomy::phantom::REGION_NAME {
            p.push(format!(
                "habitus is for the procedural lumbar phantom ({:?}), not region {:?}",
                crate::anatomy::phantom::REGION_NAME,
                self.region
            ));
        }
        if self.modalities.is_empty() {
            p.push("a station needs at least one modality".to_string());
        }
        let mut seen = BTreeSet::new();
        for m in &self.modalities {
            if !seen.insert(m) {
                p.push(format!("modality {m:?} listed twice"));
            }
        }
        let mut instrument_ids = BTreeSet::new();
        for inst in &self.instruments {
            if !is_slug(&inst.id, '-') {
                p.push(format!(
                    "instrument id {:?} must be lowercase letters, digits, '-'",
                    inst.id
                ));
            }
            if !instrument_ids.insert(inst.id.as_str()) {
                p.push(format!("instrument id {:?} is not unique", inst.id));
            }
            if inst.kind.trim().is_empty() {
                p.push(format!("instrument {:?} has no kind", inst.id));
            }
            if let Some(len) = inst.length_mm.filter(|l| !(l.is_finite() && *l > 0.0)) {
                p.push(format!(
                    "instrument {:?} length_mm {len} must be positive",
                    inst.id
                ));
            }
        }
        let mut target_names = BTreeSet::new();
        for t in &self.targets {
            if !is_slug(&t.name, '_') {
                p.push(format!(
                    "target name {:?} must be lowercase letters, digits, '_'",
                    t.name
                ));
            }
            if !target_names.insert(t.name.as_str()) {
                p.push(format!("target name {:?} is not unique", t.name));
            }
            if t.position_mm.iter().any(|v| !v.is_finite()) {
                p.push(format!("target {:?} has a non-finite coordinate", t.name));
            }
            if let Some(l) = &t.landmark {
                let ok = !l.is_empty()
                    && l.len() <= 64
                    && l.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
                if !ok {
                    p.push(format!(
                        "target {:?} landmark {l:?} must be 1 to 64 letters, digits or '_'",
                        t.name
                    ));
                }
            }
        }
        let r = &self.rubric;
        if r.revision == 0 {
            p.push("rubric revision must be at least 1".to_string());
        }
        if !(r.pass_threshold > 0.0 && r.pass_threshold <= 1.0) {
            p.push(format!(
                "pass_threshold {} must lie in (0, 1]",
                r.pass_threshold
            ));
        }
        if r.criteria.is_empty() {
            p.push("the rubric has no criteria".to_string());
        }
        let mut criterion_ids = BTreeSet::new();
        for c in &r.criteria {
            let who = format!("criterion {:?}", c.id);
            if !is_slug(&c.id, '_') {
                p.push(format!(
                    "{who}: id must be lowercase letters, digits and '_'"
                ));
            }
            if !criterion_ids.insert(c.id.as_str()) {
                p.push(format!("{who}: id is not unique"));
            }
            if c.description.trim().is_empty() {
                p.push(format!("{who}: description is empty"));
            }
            if !(c.weight.is_finite() && c.weight > 0.0) {
                p.push(format!(
                    "{who}: weight {} must be positive and finite",
                    c.weight
                ));
            }
            if !is_slug(&c.measurement, '_') {
                p.push(format!(
                    "{who}: measurement key {:?} is not snake_case",
                    c.measurement
                ));
            }
            let suffix = format!("_{}", c.unit.name());
            if !c.measurement.ends_with(&suffix) {
                p.push(format!(
                    "{who}: measurement key {:?} must end in {suffix:?} to carry its unit",
                    c.measurement
                ));
            }
            let boolean_law = matches!(c.tolerance, Tolerance::Boolean { .. });
            if boolean_law != (c.unit == Unit::Bool) {
                p.push(format!(
                    "{who}: the boolean law goes with unit \"bool\" and only with it"
                ));
            }
            for problem in c.tolerance.problems() {
                p.push(format!("{who}: {problem}"));
            }
            if let Some(t) = c
                .target
                .as_ref()
                .filter(|t| !target_names.contains(t.as_str()))
            {
                p.push(format!(
                    "{who}: target {t:?} is not one of the station's targets"
                ));
            }
        }
        p
    }

    /// Ok when [`Station::problems`] is empty.
    pub fn validate(&self) -> Result<(), StationError> {
        let problems = self.problems();
        if problems.is_empty() {
            Ok(())
        } else {
            Err(StationError::Invalid {
                station: self.id.clone(),
                problems,
            })
        }
    }

    /// Look up a target by name.
    pub fn target(&self, name: &str) -> Option<&Target> {
        self.targets.iter().find(|t| t.name == name)
    }
}

/// Load and validate every `*.toml` station in a directory, sorted by file name. Each file's stem
/// must equal its station id, and ids must be unique.
pub fn load_station_dir(dir: &Path) -> Result<Vec<StationFile>, StationError> {
    let io = |path: &Path, e: std::io::Error| StationError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    let mut paths = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| io(dir, e))? {
        let path = entry.map_err(|e| io(dir, e))?.path();
        if path.extension().is_some_and(|x| x == "toml") {
            paths.push(path);
        }
    }
    paths.sort();
    let mut files: Vec<StationFile> = Vec::with_capacity(paths.len());
    for path in paths {
        let text = std::fs::read_to_string(&path).map_err(|e| io(&path, e))?;
        let shown = path.display().to_string();
        let station: Station = toml::from_str(&text).map_err(|e| StationError::Parse {
            path: Some(shown.clone()),
            message: e.to_string(),
        })?;
        let mut problems = station.problems();
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or_default();
        if stem != station.id {
            problems.push(format!(
                "file name {stem:?} differs from station id {:?}",
                station.id
            ));
        }
        if files.iter().any(|f| f.station.id == station.id) {
            problems.push(format!(
                "station id {:?} is used by another file",
                station.id
            ));
        }
        if !problems.is_empty() {
            return Err(StationError::Invalid {
                station: shown,
                problems,
            });
        }
        files.push(StationFile {
            path,
            text,
            station,
        });
    }
    Ok(files)
}
