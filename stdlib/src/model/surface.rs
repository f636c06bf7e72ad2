//! A neural SDF rendered as a volume with a learned colour (VolSDF, NeuS),
//! its hash grid's empty space skipped.

use super::{describe_encoding as enc, network, Model};
use crate::value::{Backend, DataBackground, Encoding, NeuralSurface, Precision};
use crate::work::{Cost, SURFACE_KEPT_SHARE};

/// Bytes of the buffers per sample: every SDF layer's values, three
/// tangents and their slopes, and the colour network's activations.
fn bytes_per_sample(n: &NeuralSurface) -> f64 {
    let s = &n.sdf;
    (4 * (3 * 4 * (s.layers + 1) * s.width
        + 4 * s.encoding_width()
        + 2 * n.color_layers * n.color_width
        + n.color_input()
        + 16)) as f64
}

impl Model for NeuralSurface {
    fn describe(&self, _: &dyn Fn(Precision) -> String) -> String {
        let n = self;
        format!(
            "neural SDF as a {:?} volume (alpha {}, beta {}{}): {} position, {}x{} softplus layers with the exact gradient at every sample; colour network {}x{} ReLU on the point, the normal{}; {} multiply-adds per sample",
            n.density,
            n.alpha,
            n.beta,
            match (n.train_beta, n.beta_end) {
                (true, _) => ", trained".to_string(),
                (false, Some(end)) => format!(" falling to {end} over the steps"),
                (false, None) => String::new(),
            },
            enc(&n.sdf.encoding),
            n.sdf.layers,
            n.sdf.width,
            n.color_layers,
            n.color_width,
            if n.view_dependent {
                " and the view direction"
            } else {
                " (no view direction)"
            },
            n.multiply_adds_per_sample()
        )
    }

    fn data_background(&self) -> DataBackground {
        DataBackground::Color(glam::DVec3::from_array(self.background))
    }

    fn volume_sample(&self) -> f64 {
        network(self.multiply_adds_per_sample())
    }

    fn volume_buffers(&self) -> f64 {
        0.0
    }

    // A distance and its gradient.
    fn geometry_point(&self) -> f64 {
        4.0 * network(self.sdf.multiply_adds())
    }

    fn export_sample(&self) -> f64 {
        self.geometry_point()
    }

    fn render_pixel(&self, samples: f64) -> f64 {
        samples * network(self.multiply_adds_per_sample())
    }

    // Samples of 16 384 a pass.
    fn render_buffers(&self) -> f64 {
        16_384.0 * bytes_per_sample(self)
    }

    fn train_ray(&self, samples: f64, _: usize) -> f64 {
        3.0 * samples * network(self.multiply_adds_per_sample())
    }

    fn batch_bytes(&self, rays: f64, samples: f64, _: Backend) -> f64 {
        rays * samples * bytes_per_sample(self)
    }

    fn trained_numbers(&self, _: usize) -> f64 {
        self.weights() as f64
    }

    // The grid that skips empty space keeps a distance a cell (its state),
    // copied as an occupancy grid's is.
    fn grid_cells(&self) -> f64 {
        if self.skips_empty_space() {
            (NeuralSurface::SKIP_CELLS as f64).powi(3)
        } else {
            0.0
        }
    }

    // Every cell's distance each refresh; the centres, this refresh's
    // distances and the last's.
    fn grid_refresh(&self, iterations: f64) -> Cost {
        let cells = self.grid_cells();
        if cells == 0.0 {
            return Cost::default();
        }
        let every = NeuralSurface::SKIP_EVERY as f64;
        Cost::all(
            (iterations / every).ceil() * cells * network(self.sdf.multiply_adds()),
            cells * 20.0,
        )
    }

    fn expected_share(&self) -> f64 {
        if self.skips_empty_space() {
            SURFACE_KEPT_SHARE
        } else {
            1.0
        }
    }

    // A surface's tangents through a hash grid gather more than a NeRF's.
    fn training_pace(&self) -> f64 {
        match self.sdf.encoding {
            Encoding::HashGrid(_) => 4.0,
            Encoding::Harmonic(_) => 0.3,
        }
    }

    fn thread_scratch(&self) -> f64 {
        self.sdf.thread_scratch() as f64
    }
}
