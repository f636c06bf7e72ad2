//! The trained field: what a `train` statement fits, seen from the job.
//! [`Objective`] is what the loop needs (tensors, loss and gradient,
//! projection, schedules, state); [`TrainedField`] adds what the job does
//! with the values it reaches: render a view, give a distance field for
//! meshes or a density for exports, list the parameters a report shows and
//! describe itself. Each model implements both beside its objective, so
//! the job matches the model kind once, when it builds the field.

use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::num::{Dual, V3};
use sdfl_stdlib::shape::ArgSource;
use sdfl_stdlib::value::{Backend, Sampler};

use super::model::{field_at, DualArgs};
use super::objective::{FieldObjective, Objective};
use super::TrainError;
use crate::export::{Analytic, RadianceField};
use crate::mesh::DistanceField;
use crate::metrics::SdfFit;
use crate::volume::render::{render_field_image_with, DensityModel};
use crate::volume::{ImageSize, Stratified};

/// A region of space, as its lowest and highest corners.
pub type Region = ([f64; 3], [f64; 3]);

/// One rendered view: each pixel's colour and (when asked) its expected
/// depth, row by row.
pub struct View {
    /// Colour per pixel.
    pub colour: Vec<[f32; 3]>,
    /// Depth per pixel (empty when not asked for, where the field can skip it).
    pub depth: Vec<f32>,
    /// Accumulated opacity per pixel, where the field renders it (a NeRF;
    /// else empty): with the depth, what depth exports keep or drop.
    pub opacity: Vec<f32>,
}

impl View {
    /// Each pixel's ray end (the colour as rendered, `Σ wᵢtᵢ`, `Σ wᵢ`),
    /// where the view has depths and opacities.
    pub fn ray_ends(&self) -> Option<Vec<crate::export::RayEnd>> {
        let n = self.colour.len();
        (self.depth.len() == n && self.opacity.len() == n).then(|| {
            self.colour
                .iter()
                .zip(&self.depth)
                .zip(&self.opacity)
                .map(|((&colour, &depth), &opacity)| crate::export::RayEnd {
                    colour,
                    depth,
                    opacity,
                })
                .collect()
        })
    }
}

/// What a trained field is and how it trains, for `sdfl plan`.
#[derive(Debug, Clone, PartialEq)]
pub struct Description {
    /// What training changes: its parameters or weights, counted.
    pub trainable: String,
    /// How its gradient is computed (a traced tape, forward-mode
    /// tangents, hand-written backward passes, a dfdx graph).
    pub gradient: String,
    /// The region a mesh with `bounds: "auto"` covers.
    pub mesh_region: String,
}

/// A field being trained, as the job uses it between and after steps.
pub trait TrainedField: Objective + Sync {
    /// The view from `cam` at `values`, `size` pixels; depth only where
    /// `want_depth` (a field may give it anyway).
    fn render_view(
        &self,
        values: &[f32],
        cam: &Camera,
        size: ImageSize,
        want_depth: bool,
    ) -> Result<View, String>;

    /// The signed distance at `values`, for meshes; `None` for a field
    /// with no surface (a radiance field).
    fn surface<'a>(&'a self, _values: &'a [f32]) -> Option<Box<dyn DistanceField + 'a>> {
        None
    }

    /// Whether [`TrainedField::render_view`] with depth also gives each
    /// pixel's opacity (a NeRF's, skipping what its training skips): then
    /// depth exports read its renders ([`View::ray_ends`]) instead of
    /// marching every sample of [`TrainedField::radiance`].
    fn renders_opacity(&self) -> bool {
        false
    }

    /// Density and colour at `values`, for field exports; `None` for a
    /// field with no density (a distance network).
    fn radiance<'a>(&'a self, _values: &'a [f32]) -> Option<Box<dyn RadianceField + 'a>> {
        None
    }

    /// The region a mesh or an export with `bounds: "auto"` covers.
    fn region(&self) -> Option<Region>;

    /// The surface of a distance network traced from `cam`, normals as
    /// colours (a `geometry_gif`'s frame); `None` for other fields.
    fn geometry_view(
        &self,
        _values: &[f32],
        _cam: &Camera,
        _size: ImageSize,
    ) -> Option<Result<Vec<[f32; 3]>, String>> {
        None
    }

    /// The parameters a report lists by name, with their values (a
    /// network's weights are not listed; a trained β is, as β).
    fn reported(&self, values: &[f32]) -> Vec<(String, Vec<f32>)>;

    /// Parameters that the projection holds at an edge of their range they
    /// did not start at.
    fn held_at_bounds(&self, _values: &[f32]) -> Vec<String> {
        Vec::new()
    }

    /// How well the field fits `points` (a distance network fitted to a
    /// point cloud); `None` for other fields.
    fn fit_to_points(&self, _values: &[f32], _points: &[[f32; 3]], _seed: u64) -> Option<SdfFit> {
        None
    }

    /// Whether its values are a network's weights (reports count them
    /// rather than list them, and progress shows none).
    fn is_network(&self) -> bool;

    /// What the field is and how it trains.
    fn describe(&self) -> Description;
}

/// How a trained field is seen: the statement's sampler (and its strata)
/// and the region `bounds: "auto"` stands for.
#[derive(Debug, Clone)]
pub struct Viewing {
    /// The statement's sampler.
    pub sampler: Sampler,
    /// Its stratified depths.
    pub strat: Stratified,
    /// The region meshes and exports cover by default.
    pub region: Option<Region>,
}

impl Viewing {
    /// `sampler`'s viewing, with `region` for `bounds: "auto"`.
    pub fn new(sampler: &Sampler, region: Option<Region>) -> Result<Self, String> {
        let strat = Stratified::new(sampler.samples, sampler.near as f32, sampler.far as f32)
            .map_err(|e| e.to_string())?;
        Ok(Viewing {
            sampler: *sampler,
            strat,
            region,
        })
    }
}

/// An objective with how it is seen: the trained field of a model whose
/// objective alone does not know the sampler or its region.
pub struct Trained<O> {
    /// The objective the loop fits.
    pub objective: O,
    /// Its sampler and region.
    pub viewing: Viewing,
}

impl<O: Objective> Objective for Trained<O> {
    fn tensors(&self) -> Vec<super::TensorSpec> {
        self.objective.tensors()
    }
    fn initial(&self) -> Vec<f32> {
        self.objective.initial()
    }
    fn loss_and_grad(
        &mut self,
        values: &[f32],
        batch: &super::fused::Batch,
        weight: f64,
        grad: &mut [f32],
    ) -> Result<f64, TrainError> {
        self.objective.loss_and_grad(values, batch, weight, grad)
    }
    fn project(&self, values: &mut [f32]) {
        self.objective.project(values)
    }
    fn at_step(&self, step: usize, values: &mut [f32]) {
        self.objective.at_step(step, values)
    }
    fn state(&self) -> Vec<(String, Vec<f32>)> {
        self.objective.state()
    }
    fn samples_evaluated(&self) -> Option<u64> {
        self.objective.samples_evaluated()
    }
    fn restore_state(&mut self, state: &[(String, Vec<f32>)]) -> Result<(), TrainError> {
        self.objective.restore_state(state)
    }
}

/// The starting bounds of an analytic field's shape grown by half their
/// size (the fit moves the shape): its meshes' and exports' region.
pub fn grown_bounds(shape: &sdfl_stdlib::shape::Shape) -> Option<Region> {
    shape.bounds().map(|b| {
        let b = b.expand(0.5 * (b.max - b.min).max_element());
        (b.min.to_array(), b.max.to_array())
    })
}

impl Trained<FieldObjective<'_>> {
    /// The field's density at `args`' values.
    fn density(&self, args: &DualArgs<'_, f32, 0>) -> DensityModel {
        let f = &self.objective.model.field;
        DensityModel {
            kind: f.density,
            alpha: args.scalar(&f.alpha).v,
            beta: args.scalar(&f.beta).v,
            last_interval: self.viewing.sampler.last_interval,
        }
    }
}

impl TrainedField for Trained<FieldObjective<'_>> {
    fn render_view(
        &self,
        values: &[f32],
        cam: &Camera,
        size: ImageSize,
        want_depth: bool,
    ) -> Result<View, String> {
        let model = &*self.objective.model;
        let args = model.plain(values);
        let eval = |p: [f32; 3]| {
            let q = V3::from_array(p.map(Dual::constant));
            let (d, c) = field_at(model, &args, q);
            (d.v, [c.x.v, c.y.v, c.z.v])
        };
        let img = render_field_image_with(
            eval,
            self.density(&args),
            &self.viewing.strat,
            cam,
            size,
            want_depth,
        )
        .map_err(|e| e.to_string())?;
        Ok(View {
            colour: img.colour,
            depth: img.depth,
            opacity: Vec::new(),
        })
    }

    fn surface<'a>(&'a self, values: &'a [f32]) -> Option<Box<dyn DistanceField + 'a>> {
        let model = &*self.objective.model;
        let args = model.plain(values);
        Some(Box::new(move |p: &[[f32; 3]], out: &mut [f32]| {
            for (p, o) in p.iter().zip(out) {
                let q = V3::from_array(p.map(Dual::constant));
                *o = field_at(model, &args, q).0.v;
            }
        }))
    }

    fn radiance<'a>(&'a self, values: &'a [f32]) -> Option<Box<dyn RadianceField + 'a>> {
        let model = &*self.objective.model;
        let args = model.plain(values);
        let density = self.density(&args);
        Some(Box::new(Analytic {
            field: move |p: [f32; 3]| {
                let q = V3::from_array(p.map(Dual::constant));
                let (d, c) = field_at(model, &args, q);
                (d.v, [c.x.v, c.y.v, c.z.v])
            },
            model: density,
        }))
    }

    fn region(&self) -> Option<Region> {
        self.viewing.region
    }

    fn reported(&self, values: &[f32]) -> Vec<(String, Vec<f32>)> {
        self.objective
            .tensors()
            .into_iter()
            .map(|t| (t.name, values[t.offset..t.offset + t.len].to_vec()))
            .collect()
    }

    fn held_at_bounds(&self, values: &[f32]) -> Vec<String> {
        let model = &*self.objective.model;
        let start = model.initial_values();
        model
            .params
            .iter()
            .filter(|p| {
                let (lo, hi) = p.bound.limits();
                (p.offset..p.offset + p.len).any(|i| {
                    let (v, s) = (values[i] as f64, start[i]);
                    [lo, hi]
                        .iter()
                        .any(|&b| b.is_finite() && v == b as f32 as f64 && s != b)
                })
            })
            .map(|p| p.name.clone())
            .collect()
    }

    fn is_network(&self) -> bool {
        false
    }

    fn describe(&self) -> Description {
        let model = &*self.objective.model;
        let params: Vec<String> = model
            .params
            .iter()
            .map(|p| format!("{} ({})", p.name, p.len))
            .collect();
        Description {
            trainable: format!("{} (gradients only for these)", params.join(", ")),
            gradient: match self.objective.backend {
                Backend::Dfdx => {
                    "dfdx autodiff graph over [rays, samples], the field as a custom op".into()
                }
                Backend::Fused => fused_kernel(model, self.viewing.sampler.samples),
            },
            mesh_region: "the starting bounds grown by half".into(),
        }
    }
}

/// What the fused kernel runs for an analytic field: its traced tape (at
/// the starting values) or, where the field branches on the sample,
/// forward-mode tangents.
fn fused_kernel(model: &super::TrainModel, samples: usize) -> String {
    let values: Vec<f32> = model.initial_values().iter().map(|&x| x as f32).collect();
    match super::fused::tape_for(model, &values, samples) {
        Ok(tape) => format!(
            "traced each step: {} operations a sample forward, {} in reverse on 16 samples at a time, one reverse pass for all {} scalars",
            tape.len(),
            tape.reverse_len(),
            model.scalars
        ),
        Err(why) => format!(
            "fused per-ray kernel: forward-mode tangents for each parameter (not traced: {why})"
        ),
    }
}

/// The analytic field of `model`, differentiated by `backend`.
pub fn analytic(
    model: super::TrainModel,
    backend: Backend,
    sampler: &Sampler,
) -> Result<Trained<FieldObjective<'static>>, String> {
    let region = grown_bounds(&model.field.shape);
    Ok(Trained {
        objective: FieldObjective::owning(model, backend),
        viewing: Viewing::new(sampler, region)?,
    })
}
