//! Reading an OptiOdom set from its files: the metadata rows, each run's samples (bounded,
//! checked, a malformed line named with its number) and the set as a whole.

use super::*;

impl OptiOdomSet {
    /// Reads the sets in `dirs`, in that order.
    pub fn load_all(dirs: &[PathBuf]) -> Result<Vec<Self>, DatasetError> {
        dirs.iter().map(OptiOdomSet::load).collect()
    }

    /// Reads a set from its directory.
    pub fn load(dir: impl AsRef<Path>) -> Result<Self, DatasetError> {
        let dir = dir.as_ref();
        let mut meta_path = None;
        let mut run_paths = Vec::new();
        for entry in std::fs::read_dir(dir).map_err(io_err(dir))? {
            let path = entry.map_err(io_err(dir))?.path();
            let name = path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            if name.ends_with("_metadata.csv") {
                meta_path = Some(path);
            } else if name.contains("_run-") && name.ends_with(".csv") {
                run_paths.push(path);
            }
        }
        let (Some(meta_path), false) = (meta_path, run_paths.is_empty()) else {
            return Err(DatasetError::NotASet(dir.to_path_buf()));
        };
        run_paths.sort();
        let meta = read_metadata(&meta_path)?;
        let counts_per_wheel_rev =
            meta_one(&meta, &meta_path, "ngear")? * meta_one(&meta, &meta_path, "encRes")?;
        let wheelbase_m = meta_one(&meta, &meta_path, "Li")?;
        let diameters = meta_values(&meta, &meta_path, "Di")?;
        let (left, right) = match diameters.as_slice() {
            [d] => (*d, *d),
            [l, r, ..] => (*l, *r),
            [] => {
                return Err(DatasetError::Metadata {
                    path: meta_path,
                    key: "Di",
                    reason: "has no value".into(),
                })
            }
        };
        let side_m = meta_values(&meta, &meta_path, "L")
            .ok()
            .and_then(|v| v.first().copied());
        // Physical ranges before anything is computed from them (a 1e300 diameter or 1e18
        // ticks would otherwise make every later loop meaningless or endless).
        use crate::kinematics::{
            PHYSICAL_COUNTS_PER_REV, PHYSICAL_DIAMETER_M, PHYSICAL_WHEELBASE_M,
        };
        for (key, value, (lo, hi)) in [
            ("Di", left.min(right), PHYSICAL_DIAMETER_M),
            ("Di", left.max(right), PHYSICAL_DIAMETER_M),
            ("Li", wheelbase_m, PHYSICAL_WHEELBASE_M),
            ("encRes", counts_per_wheel_rev, PHYSICAL_COUNTS_PER_REV),
            ("L", side_m.unwrap_or(1.0), (1e-2, 100.0)),
        ] {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err(DatasetError::Metadata {
                    path: meta_path.clone(),
                    key,
                    reason: format!("{value} is outside [{lo}, {hi}]"),
                });
            }
        }
        let max_counts_per_s =
            MAX_WHEEL_SPEED_M_S * counts_per_wheel_rev / (std::f64::consts::PI * left.min(right));
        let runs = run_paths
            .iter()
            .map(|p| read_run(p, max_counts_per_s))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(OptiOdomSet {
            id: dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            configured: WheelParams {
                left_wheel_diameter_m: left,
                right_wheel_diameter_m: right,
                wheelbase_m,
                counts_per_wheel_rev,
            },
            side_m,
            runs,
        })
    }
}

pub(super) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.to_path_buf(),
        source,
    }
}

pub(super) fn reader(
    path: &Path,
) -> Result<csv::Reader<std::io::Take<std::fs::File>>, DatasetError> {
    let file = crate::io::open_bounded(path, crate::io::MAX_DATA_FILE).map_err(io_err(path))?;
    Ok(csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(file))
}

pub(super) fn malformed(path: &Path, line: u64, reason: impl Into<String>) -> DatasetError {
    DatasetError::Malformed {
        path: path.to_path_buf(),
        line,
        reason: reason.into(),
    }
}

/// The metadata rows as `key -> non-empty values`.
pub(super) fn read_metadata(path: &Path) -> Result<Vec<(String, Vec<String>)>, DatasetError> {
    let mut rows = Vec::new();
    for (i, rec) in reader(path)?.records().enumerate() {
        let rec = rec.map_err(|e| malformed(path, i as u64 + 1, e.to_string()))?;
        let mut fields = rec.iter();
        let Some(key) = fields.next() else { continue };
        let values = fields
            .filter(|v| !v.trim().is_empty())
            .map(|v| v.trim().to_string())
            .collect();
        rows.push((key.trim().to_string(), values));
    }
    Ok(rows)
}

pub(super) fn meta_values(
    meta: &[(String, Vec<String>)],
    path: &Path,
    key: &'static str,
) -> Result<Vec<f64>, DatasetError> {
    let values = meta
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v)
        .ok_or_else(|| DatasetError::Metadata {
            path: path.to_path_buf(),
            key,
            reason: "missing".into(),
        })?;
    values
        .iter()
        .map(|v| {
            v.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && *x > 0.0)
                .ok_or_else(|| DatasetError::Metadata {
                    path: path.to_path_buf(),
                    key,
                    reason: format!("{v:?} is not a positive number"),
                })
        })
        .collect()
}

pub(super) fn meta_one(
    meta: &[(String, Vec<String>)],
    path: &Path,
    key: &'static str,
) -> Result<f64, DatasetError> {
    meta_values(meta, path, key)?
        .first()
        .copied()
        .ok_or_else(|| DatasetError::Metadata {
            path: path.to_path_buf(),
            key,
            reason: "has no value".into(),
        })
}

/// The nominal cycle of the data set (s), for the first row, which has no previous time.
pub(super) const CYCLE_S: f64 = 0.05;

pub(super) fn read_run(path: &Path, max_counts_per_s: f64) -> Result<RecordedRun, DatasetError> {
    let mut samples: Vec<Sample> = Vec::new();
    for (i, rec) in reader(path)?.records().enumerate() {
        let line = i as u64 + 1;
        let rec = rec.map_err(|e| malformed(path, line, e.to_string()))?;
        if rec.len() != 6 {
            return Err(malformed(
                path,
                line,
                format!("expected 6 columns, found {}", rec.len()),
            ));
        }
        let mut v = [0.0; 6];
        for (k, field) in rec.iter().enumerate() {
            v[k] = field
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    malformed(
                        path,
                        line,
                        format!("column {}: {field:?} is not a number", k + 1),
                    )
                })?;
        }
        let dt = match samples.last() {
            Some(prev) if v[0] > prev.time_s => v[0] - prev.time_s,
            Some(prev) => {
                return Err(malformed(
                    path,
                    line,
                    format!(
                        "time {} s does not follow {} s (time must go forward)",
                        v[0], prev.time_s
                    ),
                ))
            }
            None => CYCLE_S,
        };
        let limit = max_counts_per_s * dt + 2.0;
        for (col, ticks) in [(5, v[4]), (6, v[5])] {
            if ticks.abs() > limit {
                return Err(malformed(
                    path,
                    line,
                    format!(
                        "column {col}: {ticks} ticks in {dt:.3} s is more than a wheel at \
                         {MAX_WHEEL_SPEED_M_S} m/s turns ({limit:.0})"
                    ),
                ));
            }
        }
        samples.push(Sample {
            time_s: v[0],
            truth: Pose::new(v[1], v[2], v[3]),
            right_counts: v[4],
            left_counts: v[5],
        });
    }
    if samples.len() < 2 {
        return Err(malformed(
            path,
            samples.len() as u64,
            "a run needs at least two samples",
        ));
    }
    Ok(RecordedRun {
        name: path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        samples,
    })
}
