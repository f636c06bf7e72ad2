//! A field prepared for training: its distinct parameters (one per
//! `param(...)` call, however often used), their names, ranges and places
//! in one flat vector, and the argument source that reads them as
//! forward-mode [`Dual`] numbers.

use std::collections::HashMap;
use std::sync::Arc;

use glam::DVec3;
use sdfl_stdlib::num::{Dual, Real, V3};
use sdfl_stdlib::param::{Arg, Bound, ParamDecl, ParamInit};
use sdfl_stdlib::shape::ArgSource;
use sdfl_stdlib::value::SdfField;

/// One trainable parameter.
#[derive(Debug, Clone)]
pub struct ModelParam {
    /// The `param(...)` call that declares it.
    pub decl: Arc<ParamDecl>,
    /// Its `let` name, or where it is first used (`torus.major`), made
    /// unique with `#2`, `#3`….
    pub name: String,
    /// The ranges of all its uses at once.
    pub bound: Bound,
    /// First scalar in the flat vector.
    pub offset: usize,
    /// Number of scalars it holds.
    pub len: usize,
}

/// A field and its parameters.
#[derive(Debug, Clone)]
pub struct TrainModel {
    /// The signed-distance field, colour and density being fitted.
    pub field: SdfField,
    /// Each distinct `param(...)` the field uses, in order of first use.
    pub params: Vec<ModelParam>,
    /// Flat offset of each `ParamDecl::id`, `usize::MAX` for parameters of
    /// the file that this model does not use.
    offsets: Vec<usize>,
    /// Number of scalars.
    pub scalars: usize,
    /// The first `field_scalars` scalars are those the field (shape and
    /// colour) depends on; the rest (α and β used nowhere else) reach the
    /// loss through the density only.
    pub field_scalars: usize,
}

impl TrainModel {
    /// The model of `field`: each of its parameters once, laid out in a flat vector.
    pub fn new(field: &SdfField) -> Self {
        let mut params: Vec<ModelParam> = Vec::new();
        // Each `param(...)` call once, however often it is used.
        let mut seen: HashMap<*const ParamDecl, usize> = HashMap::new();
        let mut scalars = 0;
        field.visit_params(&mut |u| {
            if let Some(&i) = seen.get(&Arc::as_ptr(&u.decl)) {
                params[i].bound = params[i].bound.and(u.bound);
                return;
            }
            seen.insert(Arc::as_ptr(&u.decl), params.len());
            let len = u.decl.init.len();
            params.push(ModelParam {
                decl: u.decl.clone(),
                name: u.decl.binding.clone().unwrap_or_else(|| u.site.clone()),
                bound: u.bound,
                offset: scalars,
                len,
            });
            scalars += len;
        });
        // Unique names: a second `sphere.center` becomes `sphere.center#2`.
        let mut count: HashMap<String, usize> = HashMap::new();
        for p in &mut params {
            let n = count.entry(p.name.clone()).or_insert(0);
            *n += 1;
            if *n > 1 {
                p.name = format!("{}#{}", p.name, n);
            }
        }
        let max_id = params.iter().map(|p| p.decl.id).max().map_or(0, |m| m + 1);
        let mut offsets = vec![usize::MAX; max_id];
        for p in &params {
            offsets[p.decl.id] = p.offset;
        }
        // Shape and colour are visited before α and β, so their parameters
        // come first.
        let mut field_scalars = 0;
        let mut field_use = |u: &sdfl_stdlib::param::ParamUse| {
            let p = &params[seen[&Arc::as_ptr(&u.decl)]];
            field_scalars = field_scalars.max(p.offset + p.len);
        };
        field.shape.visit_params(&mut field_use);
        field.color.visit_params(&mut field_use);
        TrainModel {
            field: field.clone(),
            params,
            offsets,
            scalars,
            field_scalars,
        }
    }

    /// The starting values, projected into their ranges.
    pub fn initial_values(&self) -> Vec<f64> {
        let mut v = vec![0.0; self.scalars];
        for p in &self.params {
            let init = match p.decl.init {
                ParamInit::Scalar(x) => vec![x],
                ParamInit::Vec3(x) => x.to_array().to_vec(),
            };
            for (k, x) in init.into_iter().enumerate() {
                v[p.offset + k] = p.bound.project(x);
            }
        }
        v
    }

    /// Projects every value into its parameter's range (after a step).
    pub fn project(&self, values: &mut [f32]) {
        for p in &self.params {
            for x in &mut values[p.offset..p.offset + p.len] {
                *x = p.bound.project(*x as f64) as f32;
            }
        }
    }

    /// The flat index of a scalar argument's parameter, if it has one in
    /// this model.
    pub fn scalar_index(&self, a: &Arg<f64>) -> Option<usize> {
        let u = a.param.as_ref()?;
        Some(self.offset(&u.decl)).filter(|&o| o != usize::MAX)
    }

    /// The flat index of a vector argument's parameter and the parameter's
    /// form (a scalar parameter fills all three components).
    pub fn vector_index(&self, a: &Arg<DVec3>) -> Option<(usize, ParamInit)> {
        let u = a.param.as_ref()?;
        Some(self.offset(&u.decl))
            .filter(|&o| o != usize::MAX)
            .map(|o| (o, u.decl.init))
    }

    fn offset(&self, decl: &ParamDecl) -> usize {
        self.offsets.get(decl.id).copied().unwrap_or(usize::MAX)
    }

    /// The arguments at `values`, with tangents for the `N` scalars from
    /// `first` on.
    pub fn args<'a, F: Real, const N: usize>(
        &'a self,
        values: &'a [F],
        first: usize,
    ) -> DualArgs<'a, F, N> {
        DualArgs {
            model: self,
            values,
            first,
        }
    }

    /// The arguments at `values` as plain numbers (rendering a trained field).
    pub fn plain<'a, F: Real>(&'a self, values: &'a [F]) -> DualArgs<'a, F, 0> {
        self.args(values, 0)
    }
}

/// A [`TrainModel`]'s arguments at given values, as [`Dual`]s whose tangent
/// `i` is the derivative with respect to scalar `first + i`.
pub struct DualArgs<'a, F, const N: usize> {
    model: &'a TrainModel,
    values: &'a [F],
    first: usize,
}

impl<F: Real, const N: usize> DualArgs<'_, F, N> {
    #[inline(always)]
    fn scalar_at(&self, i: usize) -> Dual<F, N> {
        Dual::seed(self.values[i], i.wrapping_sub(self.first))
    }
}

impl<F: Real, const N: usize> ArgSource<Dual<F, N>> for DualArgs<'_, F, N> {
    #[inline(always)]
    fn scalar(&self, a: &Arg<f64>) -> Dual<F, N> {
        match &a.param {
            None => Dual::lit(a.value),
            Some(u) => match self.model.offset(&u.decl) {
                usize::MAX => Dual::lit(a.value),
                o => self.scalar_at(o),
            },
        }
    }
    #[inline(always)]
    fn vector(&self, a: &Arg<DVec3>) -> V3<Dual<F, N>> {
        match &a.param {
            None => V3::lit(a.value.to_array()),
            Some(u) => match (self.model.offset(&u.decl), u.decl.init) {
                (usize::MAX, _) => V3::lit(a.value.to_array()),
                (o, ParamInit::Scalar(_)) => V3::splat(self.scalar_at(o)),
                (o, ParamInit::Vec3(_)) => V3::new(
                    self.scalar_at(o),
                    self.scalar_at(o + 1),
                    self.scalar_at(o + 2),
                ),
            },
        }
    }
}

/// The field of `model` at `p`: signed distance and colour.
#[inline(always)]
pub fn field_at<T: Real, A: sdfl_stdlib::shape::ArgSource<T>>(
    model: &TrainModel,
    args: &A,
    p: V3<T>,
) -> (T, V3<T>) {
    let s = model.field.shape.sample(p, args);
    let material = s.material.unwrap_or(&model.field.color);
    // Fields refuse materials that need normals (painted ones too).
    let c = material
        .unlit_color(p, s.center, args)
        .unwrap_or(V3::splat(T::lit(0.5)));
    (s.d, c)
}
