//! Input encodings of neural fields: harmonic and multiresolution hash grid.

/// An input encoding of a neural field.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Encoding {
    /// Sines and cosines of the position (NeRF).
    Harmonic(Harmonic),
    /// A multiresolution hash grid (instant-ngp).
    HashGrid(HashGridSpec),
}

impl Encoding {
    /// Features of a 3-vector's encoding.
    pub fn width(&self) -> usize {
        match self {
            Encoding::Harmonic(h) => 3 * 2 * h.freqs + if h.include_input { 3 } else { 0 },
            Encoding::HashGrid(g) => (g.levels * g.features) as usize,
        }
    }
}

/// NeRF's harmonic embedding: `sin(2^k·x)`, `cos(2^k·x)` for
/// `k < freqs`, and `x` itself when `include_input`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Harmonic {
    /// Frequencies `2^0 … 2^(freqs−1)` per coordinate.
    pub freqs: usize,
    /// Whether the coordinates themselves are features too.
    pub include_input: bool,
}

/// A multiresolution hash encoding (Müller et al. 2022): `levels` grids
/// from `min_res` to `max_res` cells a side over the box `min..max`, each
/// a table of at most `2^log2_table` rows of `features` trainable numbers,
/// trilinearly interpolated.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HashGridSpec {
    /// Number of grids.
    pub levels: u32,
    /// Trainable numbers per table row.
    pub features: u32,
    /// Each table holds at most `2^log2_table` rows.
    pub log2_table: u32,
    /// Cells a side of the coarsest grid.
    pub min_res: u32,
    /// Cells a side of the finest grid.
    pub max_res: u32,
    /// The box's low corner; positions outside it are clamped.
    pub min: [f64; 3],
    /// The box's high corner.
    pub max: [f64; 3],
}

impl HashGridSpec {
    /// Trainable numbers in all tables.
    pub fn param_count(&self) -> u64 {
        hash_grid_levels(self.levels, self.min_res, self.max_res, self.log2_table)
            .iter()
            .map(|(_, rows)| rows * self.features as u64)
            .sum()
    }
}

/// Each level of a hash grid: its resolution (cells a side) and its table's
/// rows, dense (`(res + 1)³`) when that fits the table, else `2^log2_table`.
/// Resolutions grow geometrically from `min_res` to `max_res`, floored (with
/// 1e-9 forgiven so the top level is exactly `max_res`).
pub fn hash_grid_levels(
    levels: u32,
    min_res: u32,
    max_res: u32,
    log2_table: u32,
) -> Vec<(u32, u64)> {
    let (lmin, lmax) = ((min_res.max(1) as f64).ln(), (max_res.max(1) as f64).ln());
    let growth = if levels > 1 {
        (lmax - lmin) / (levels - 1) as f64
    } else {
        0.0
    };
    let table = 1u64 << log2_table.min(62);
    (0..levels)
        .map(|l| {
            let x = (lmin + l as f64 * growth).exp();
            let res = ((x * (1.0 + 1e-9)).floor() as u32).clamp(min_res, max_res);
            let verts = (res as u64 + 1).pow(3);
            (res, verts.min(table))
        })
        .collect()
}
