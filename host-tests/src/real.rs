//! The third-party recordings in `shared/data/real/` (beside the repository),
//! read in place: they are never copied into the repository.

use std::path::PathBuf;

/// Path of a recording in `../shared/data/real/`, relative to the workspace.
pub fn path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/real")
        .join(name)
}

/// The text of the shared recording `name`.
fn read_text(name: &str) -> String {
    let p = path(name);
    std::fs::read_to_string(&p).unwrap_or_else(|e| {
        panic!(
            "cannot read {} ({e}): is ../shared beside the repo?",
            p.display()
        )
    })
}

/// Reads the numeric columns `cols` (0-based) of a CSV or whitespace
/// separated file, skipping a header line and comments.
pub fn read_columns(name: &str, cols: [usize; 3]) -> Vec<[f64; 3]> {
    let text = read_text(name);
    text.lines()
        .filter_map(|line| {
            let fields: Vec<f64> = line
                .split(|c: char| c == ',' || c.is_whitespace())
                .filter(|f| !f.is_empty())
                .map(|f| f.parse::<f64>())
                .collect::<Result<_, _>>()
                .ok()?;
            Some([
                *fields.get(cols[0])?,
                *fields.get(cols[1])?,
                *fields.get(cols[2])?,
            ])
        })
        .collect()
}

/// Reads the first three columns.
pub fn read_xyz(name: &str) -> Vec<[f64; 3]> {
    read_columns(name, [0, 1, 2])
}

/// Reads the columns `cols` (0-based) of a CSV with a header and text
/// columns (as `imu_gnss_1252.csv`): each of the three fields parsed on
/// its own, rows where one is not a number skipped.
pub fn read_csv_fields(name: &str, cols: [usize; 3]) -> Vec<[f64; 3]> {
    let text = read_text(name);
    text.lines()
        .filter_map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let v = |i: usize| f.get(i)?.trim().parse::<f64>().ok();
            Some([v(cols[0])?, v(cols[1])?, v(cols[2])?])
        })
        .collect()
}
