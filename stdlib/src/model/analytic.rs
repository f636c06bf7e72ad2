//! An analytic SDF seen as a volume, its `param`s trained through the
//! fused kernels or the dfdx graph.

use super::Model;
use crate::value::{Backend, DataBackground, Precision, SdfField};

impl Model for SdfField {
    fn describe(&self, _: &dyn Fn(Precision) -> String) -> String {
        format!(
            "{:?} density, alpha {}, beta {}, {} primitives",
            self.density,
            self.alpha.value,
            self.beta.value,
            self.shape.primitive_count()
        )
    }

    fn data_background(&self) -> DataBackground {
        DataBackground::Color(glam::DVec3::ZERO)
    }

    fn export_region(&self) -> Option<([f64; 3], [f64; 3])> {
        let b = self.shape.bounds()?;
        Some((b.min.to_array(), b.max.to_array()))
    }

    fn volume_sample(&self) -> f64 {
        1.0
    }

    fn volume_buffers(&self) -> f64 {
        0.0
    }

    fn geometry_point(&self) -> f64 {
        self.shape.primitive_count() as f64
    }

    fn export_sample(&self) -> f64 {
        self.shape.evaluation_cost()
    }

    fn render_pixel(&self, samples: f64) -> f64 {
        samples * self.shape.evaluation_cost()
    }

    fn render_buffers(&self) -> f64 {
        0.0
    }

    // Training walks the whole model at every sample (no culling), once
    // for values and once per 16 parameters for tangents.
    fn train_ray(&self, samples: f64, params: usize) -> f64 {
        samples * self.shape.evaluation_cost() * (1.0 + params.div_ceil(16) as f64)
    }

    fn batch_bytes(&self, rays: f64, samples: f64, backend: Backend) -> f64 {
        match backend {
            // The dfdx graph keeps every op's values and gradients per
            // sample, and composites by a triangular samples × samples
            // product per ray.
            Backend::Dfdx => rays * samples * (samples * 8.0 + 256.0),
            Backend::Fused => 0.0,
        }
    }

    fn trained_numbers(&self, params: usize) -> f64 {
        params as f64
    }

    // 0.8 in the shared batch, 1.8 on the quiet machine: between.
    fn training_pace(&self) -> f64 {
        1.5
    }

    fn uses_matmul(&self, backend: Backend) -> bool {
        backend == Backend::Dfdx
    }
}
