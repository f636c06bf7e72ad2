//! A neural signed distance function fitted to points (IGR), or the
//! distance network inside a neural surface.

use super::{describe_encoding as enc, network, Model};
use crate::value::{Backend, DataBackground, Encoding, NeuralSdf, Precision};
use crate::work::{chamfer_cost, Cost, FIT_CHUNK, FIT_PROBES};

impl Model for NeuralSdf {
    fn describe(&self, _: &dyn Fn(Precision) -> String) -> String {
        format!(
            "neural SDF: {} position, {}x{} softplus(beta {}) layers{}; {} multiply-adds per point and 3x that for its exact gradient",
            enc(&self.encoding),
            self.layers,
            self.width,
            self.beta,
            if self.skips.is_empty() {
                String::new()
            } else {
                format!(" (position again at layers {:?})", self.skips)
            },
            self.multiply_adds()
        )
    }

    fn data_background(&self) -> DataBackground {
        DataBackground::Color(glam::DVec3::ZERO)
    }

    // Refused as a volume when evaluated; counted like a network.
    fn volume_sample(&self) -> f64 {
        network(self.multiply_adds())
    }

    fn volume_buffers(&self) -> f64 {
        0.0
    }

    // A distance and its gradient.
    fn geometry_point(&self) -> f64 {
        4.0 * network(self.multiply_adds())
    }

    fn export_sample(&self) -> f64 {
        self.geometry_point()
    }

    // Sphere-traced, up to 96 steps of a distance.
    fn render_pixel(&self, _: f64) -> f64 {
        96.0 * network(self.multiply_adds())
    }

    fn render_buffers(&self) -> f64 {
        (4 * 64 * ((self.layers + 1) * self.width + self.encoding_width())) as f64
    }

    // A distance and its three tangents, forward and backward, at a
    // surface and a random point per ray of the batch (not per sample).
    fn train_ray(&self, _: f64, _: usize) -> f64 {
        2.0 * 12.0 * network(self.multiply_adds())
    }

    // Every layer's values and three tangents, forward and back, for 2
    // points a ray.
    fn batch_bytes(&self, rays: f64, _: f64, _: Backend) -> f64 {
        rays * 2.0 * 8.0 * 4.0 * ((self.layers + 1) * self.width + 4 * self.encoding_width()) as f64
    }

    fn trained_numbers(&self, _: usize) -> f64 {
        self.weights() as f64
    }

    // A harmonic neural SDF is not measured: 1.
    fn training_pace(&self) -> f64 {
        match self.encoding {
            Encoding::HashGrid(_) => 2.3,
            Encoding::Harmonic(_) => 1.0,
        }
    }

    fn trains_on_points(&self) -> bool {
        true
    }

    // Random points projected onto the surface, ten passes.
    fn fit_work(&self) -> Cost {
        let probes = FIT_PROBES as f64;
        let per_row =
            (4 * (3 * self.encoding_width() + 6 * (self.layers + 1) * self.width + 16)) as f64;
        Cost::all(
            10.0 * probes * 4.0 * network(self.multiply_adds()),
            FIT_CHUNK as f64 * per_row + probes * 16.0 + chamfer_cost().memory,
        )
    }
}
