//! A simple coverage figure for the collection progress log.
//!
//! The samples collected so far are fitted with the core's algebraic
//! least-squares ellipsoid (step 1 alone, [`Method::Ls`]: one pass, no
//! iterations), and their calibrated directions `W (y - b)` are binned into
//! 12 cells: the Voronoi cells of the icosahedron's 12 vertices, equal in
//! area (about 60 deg across). The figure is the number of cells holding at
//! least one sample; a good calibration motion visits all 12.
//!
//! The provisional fit matters: directions seen from a cruder centre (the
//! running mean, or the middle of the bounding box) are biased towards the
//! equator of whatever part of the sphere has been visited, and a polar cap
//! of a sixth of the sphere then already "visits" 10 of the 12 cells. While
//! the samples do not yet determine an ellipsoid the figure is unknown.

use mag_cal_core::{calibrate, Config, Error, Method};

/// Number of direction cells.
pub const CELLS: usize = 12;

/// Golden ratio: the icosahedron's vertices are the cyclic permutations of
/// `(0, +-1, +-PHI)`.
const PHI: f32 = 1.618_034;

/// Cell centres (unnormalised; all have the same length).
const CENTRES: [[f32; 3]; CELLS] = [
    [0.0, 1.0, PHI],
    [0.0, -1.0, PHI],
    [0.0, 1.0, -PHI],
    [0.0, -1.0, -PHI],
    [1.0, PHI, 0.0],
    [-1.0, PHI, 0.0],
    [1.0, -PHI, 0.0],
    [-1.0, -PHI, 0.0],
    [PHI, 0.0, 1.0],
    [-PHI, 0.0, 1.0],
    [PHI, 0.0, -1.0],
    [-PHI, 0.0, -1.0],
];

/// Number of the 12 direction cells visited by `samples`, or why the
/// provisional ellipsoid fit failed.
pub fn cells_visited(samples: &[[i16; 3]]) -> Result<usize, Error> {
    let config = Config {
        method: Method::Ls,
        ..Config::default()
    };
    let cal = calibrate::<f32, _>(samples, &config)?.calibration;
    let mut visited = [false; CELLS];
    for s in samples {
        let u = cal.apply(s.map(f32::from));
        // Nearest centre = largest dot product (the centres have equal norm).
        let mut best = (0, f32::NEG_INFINITY);
        for (k, c) in CENTRES.iter().enumerate() {
            let dot = c[0] * u.x + c[1] * u.y + c[2] * u.z;
            if dot > best.1 {
                best = (k, dot);
            }
        }
        visited[best.0] = true;
    }
    Ok(visited.iter().filter(|&&v| v).count())
}
