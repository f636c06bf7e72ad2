//! A neural radiance field: its networks' costs, its occupancy grid's
//! refreshes, its learned background.

use super::{describe_encoding as enc, network, Model, NETWORK_PASS, TRAIN_PASS_SAMPLES};
use crate::value::{
    occupancy_refresh_cells, Backend, Background, DataBackground, Encoding, Nerf, Precision,
    Unbounded, UNBOUNDED_GRID_START,
};
use crate::work::{Cost, CONTRACTED_OCCUPIED_SHARE, OCCUPIED_SHARE};

/// Multiply-adds of a NeRF sample's forward pass, its encoding included (a
/// hash grid interpolates eight corners a level).
fn sample_multiply_adds(n: &Nerf) -> usize {
    let encoding = match &n.position {
        Encoding::HashGrid(g) => (g.levels * 8 * (g.features + 4)) as usize,
        Encoding::Harmonic(_) => 0,
    };
    // A contracted position: a handful of operations, about 10
    // multiply-adds' worth.
    let contraction = if n.unbounded.is_some() { 10 } else { 0 };
    n.multiply_adds_per_sample() + encoding + contraction
}

/// Evaluations of the learned background per ray (0 for a colour).
fn background_evaluations(n: &Nerf) -> f64 {
    match n.background {
        Background::Learned(l) => network(l.multiply_adds()),
        Background::Data | Background::Color(_) => 0.0,
    }
}

/// Bytes of the buffers per sample of a pass: the encoding, every layer's
/// values and the colour branch, forward and back.
fn bytes_per_sample(n: &Nerf) -> f64 {
    (4 * (2 * n.position.width() + (n.layers + 4) * n.width + 2 * n.color_width + 16)) as f64
}

impl Model for Nerf {
    fn describe(&self, layer_precision: &dyn Fn(Precision) -> String) -> String {
        let n = self;
        let num = sdfl_lang::fmt_num;
        format!(
            "NeRF: {} position, {}x{} ReLU trunk{}, {} density, {}; {} multiply-adds per sample{}; {}; {}; {}{}",
            enc(&n.position),
            n.layers,
            n.width,
            if n.skips.is_empty() {
                String::new()
            } else {
                format!(" (position again at layers {:?})", n.skips)
            },
            n.density.name(),
            match &n.direction {
                Some(d) => format!(
                    "view-dependent colour ({} direction, {}-wide branch)",
                    enc(d),
                    n.color_width
                ),
                None => "colour without the view direction (no direction branch built)".into(),
            },
            n.multiply_adds_per_sample(),
            match n.fine {
                0 => " (one network)".to_string(),
                m => format!(", twice: coarse, and fine on the coarse samples + {m} by inverse CDF"),
            },
            match &n.occupancy {
                Some(o) => format!(
                    "occupancy grid {}^3 refreshed every {} steps: samples only in occupied cells",
                    o.resolution, o.every
                ),
                None => "every sample evaluated (no occupancy grid)".into(),
            },
            layer_precision(n.precision),
            match &n.background {
                Background::Data => "background: the data's".to_string(),
                Background::Color(c) => {
                    format!("background [{}, {}, {}]", num(c[0]), num(c[1]), num(c[2]))
                }
                Background::Learned(l) => format!(
                    "background learned from the ray direction (harmonic({}), {} wide)",
                    l.freqs, l.width
                ),
            },
            match &n.unbounded {
                Some(Unbounded::Ndc(_)) => "; unbounded: positions in the capture camera's NDC, samples evenly in disparity from its near plane".to_string(),
                Some(Unbounded::Contract(c)) => format!(
                    "; unbounded: positions outside [{}, {}, {}]..[{}, {}, {}] contracted into [-2, 2]^3 (mip-NeRF 360)",
                    num(c.min[0]),
                    num(c.min[1]),
                    num(c.min[2]),
                    num(c.max[0]),
                    num(c.max[1]),
                    num(c.max[2])
                ),
                None => String::new(),
            }
        )
    }

    fn data_background(&self) -> DataBackground {
        match self.background.color() {
            Some(c) => DataBackground::Color(glam::DVec3::from_array(c)),
            None => DataBackground::World,
        }
    }

    fn export_region(&self) -> Option<([f64; 3], [f64; 3])> {
        match (&self.position, &self.occupancy) {
            (Encoding::HashGrid(g), _) => Some((g.min, g.max)),
            (_, Some(o)) => Some((o.min, o.max)),
            _ => None,
        }
    }

    // In NDC all of the view is the scene: no box.
    fn object_region(&self) -> Option<([f64; 3], [f64; 3])> {
        match &self.unbounded {
            Some(Unbounded::Contract(c)) => Some((c.min, c.max)),
            Some(Unbounded::Ndc(_)) => None,
            None => self.export_region(),
        }
    }

    fn volume_sample(&self) -> f64 {
        network(sample_multiply_adds(self))
    }

    fn volume_buffers(&self) -> f64 {
        NETWORK_PASS * bytes_per_sample(self) + 4.0 * self.weights() as f64
    }

    fn geometry_point(&self) -> f64 {
        network(sample_multiply_adds(self))
    }

    fn export_sample(&self) -> f64 {
        network(sample_multiply_adds(self))
    }

    fn render_pixel(&self, samples: f64) -> f64 {
        (samples + self.fine as f64) * network(sample_multiply_adds(self))
            + background_evaluations(self)
    }

    fn render_buffers(&self) -> f64 {
        NETWORK_PASS * bytes_per_sample(self)
    }

    fn renders_depth(&self) -> bool {
        true
    }

    fn train_ray(&self, samples: f64, _: usize) -> f64 {
        // The fine network sees the coarse samples and its own.
        let fine = if self.fine > 0 {
            samples + self.fine as f64
        } else {
            0.0
        };
        // Forward and backward (about three passes); the learned
        // background once a ray.
        3.0 * (samples + fine) * network(sample_multiply_adds(self))
            + 3.0 * background_evaluations(self)
    }

    // Every layer's activations per sample of a pass (at most
    // [`TRAIN_PASS_SAMPLES`]), twice with a fine network (which sees the
    // coarse samples too), and a learned background's activations per ray,
    // forward and back.
    fn batch_bytes(&self, rays: f64, samples: f64, _: Backend) -> f64 {
        let fine = if self.fine > 0 {
            2.0 + self.fine as f64 / samples.max(1.0)
        } else {
            0.0
        };
        let background = match self.background {
            Background::Learned(l) => 4.0 * (2 * l.input() + 2 * l.width + 12) as f64,
            _ => 0.0,
        };
        let pass = (rays * samples).min(TRAIN_PASS_SAMPLES as f64);
        pass * bytes_per_sample(self) * (1.0 + fine) + rays * background
    }

    fn trained_numbers(&self, _: usize) -> f64 {
        let networks = if self.fine > 0 { 2.0 } else { 1.0 };
        self.weights() as f64 * networks + self.background_weights() as f64
    }

    fn grid_cells(&self) -> f64 {
        self.occupancy
            .as_ref()
            .map_or(0.0, |g| (g.resolution as f64).powi(3))
    }

    // The density alone at each cell refreshed; one pass of points, their
    // directions and densities.
    fn grid_refresh(&self, iterations: f64) -> Cost {
        let Some(g) = &self.occupancy else {
            return Cost::default();
        };
        let cells = self.grid_cells();
        let density = sample_multiply_adds(self) - self.multiply_adds_per_sample()
            + self.density_multiply_adds();
        Cost::all(
            occupancy_refresh_cells(cells, iterations, g.every, grid_start(self))
                * network(density),
            cells.min(NETWORK_PASS) * (bytes_per_sample(self) + 28.0),
        )
    }

    fn expected_share(&self) -> f64 {
        match (&self.occupancy, &self.unbounded) {
            (None, _) => 1.0,
            (Some(_), Some(Unbounded::Contract(_))) => CONTRACTED_OCCUPIED_SHARE,
            (Some(_), _) => OCCUPIED_SHARE,
        }
    }

    fn training_pace(&self) -> f64 {
        match self.position {
            Encoding::HashGrid(_) => 1.0,
            Encoding::Harmonic(_) => 0.45,
        }
    }
}

/// The step of a NeRF's grid's first refresh: an unbounded field's waits
/// for density to grow.
fn grid_start(n: &Nerf) -> u64 {
    if n.unbounded.is_some() {
        UNBOUNDED_GRID_START
    } else {
        0
    }
}
