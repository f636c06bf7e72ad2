//! Blocks into jobs: a block's fields are evaluated against its signature
//! (defaults filled in), the built-in that owns the block turns them into a
//! render, a volume render or a training, and the job is checked against
//! the file's limits (warnings, costs summed over the statements).

use super::*;

impl<'e> Evaluator<'e> {
    pub(super) fn block(&mut self, b: &Block, index: usize, program: &mut Program) {
        let Some(sig) = self.env.block_sig(&b.kind.name) else {
            return;
        };
        let mut args = Args::new(b.kind.span);
        args.base = self.base.clone();
        args.owner = sig.kind;
        for f in &b.fields {
            let v = self.expr(&f.value);
            if let Some(p) = sig.fields.iter().find(|p| p.name == f.name.name) {
                args.named.insert(p.name, (v, f.value.span));
            }
        }
        for p in &sig.fields {
            if let (false, Some(src)) = (args.named.contains_key(p.name), p.default) {
                let v = self.default_value(sig.kind, p.name, src);
                args.named.insert(p.name, (v, b.kind.span));
                args.defaulted.push(p.name);
            }
        }
        // Every field is checked, whatever the others hold (poison
        // included: errors about a poisoned field itself are left out).
        let poisoned = args.named.values().any(|(v, _)| v.is_poison());
        let name = b
            .name
            .as_ref()
            .map_or_else(|| format!("{}{index}", b.kind.name), |n| n.name.clone());
        let scene_field = match args.named.get("scene") {
            Some((Value::Field(f), _)) => Some(f.clone()),
            _ => None,
        };
        let kind = StatementKind::of(sig.kind, scene_field.is_some());
        let (added, errors) = match (kind, scene_field) {
            (StatementKind::Train, _) => {
                let (job, errors) = crate::builtins::train_block(&name, &args);
                (job.map(|j| program.trains.push(j)), errors)
            }
            (StatementKind::Volume, Some(f)) => {
                let (job, errors) = crate::builtins::volume_block(&name, &args, f);
                (job.map(|j| program.volumes.push(j)), errors)
            }
            (StatementKind::Render | StatementKind::Volume, _) => {
                let (job, errors) = crate::builtins::render_block(&name, &args);
                (job.map(|j| program.renders.push(j)), errors)
            }
        };
        // Warnings (a background the data disagrees with) do not fail it.
        let failed = poisoned
            || errors
                .iter()
                .any(|d| d.severity() == sdfl_lang::diag::Severity::Error);
        self.diags.diags.extend(errors);
        if added.is_none() {
            return;
        }
        let field = |name: &str| args.named.get(name).map_or(b.kind.span, |(_, s)| *s);
        program.order.push(kind.at(match kind {
            StatementKind::Render => program.renders.len(),
            StatementKind::Volume => program.volumes.len(),
            StatementKind::Train => program.trains.len(),
        } - 1));
        // A `param` outside a `train` model keeps its starting value.
        let untrained = match kind {
            StatementKind::Render => program.renders.last().and_then(|j| {
                let mut first = None;
                j.scene.visit_params(&mut |u| {
                    first.get_or_insert(u.decl.span);
                });
                first.map(|s| (s, "this render draws it at its starting value"))
            }),
            StatementKind::Volume => program.volumes.last().and_then(|j| {
                let mut first = None;
                j.field.visit_params(&mut |u| {
                    first.get_or_insert(u.decl.span);
                });
                first.map(|s| (s, "this render draws it at its starting value"))
            }),
            StatementKind::Train => program.trains.last().and_then(|j| match &*j.data {
                crate::value::Dataset::Rendered { field, .. } => {
                    let mut first = None;
                    field.visit_params(&mut |u| {
                        first.get_or_insert(u.decl.span);
                    });
                    first.map(|s| (s, "the training data is rendered at its starting value"))
                }
                crate::value::Dataset::Traced { job, .. } => {
                    let mut first = None;
                    job.scene.visit_params(&mut |u| {
                        first.get_or_insert(u.decl.span);
                    });
                    first.map(|s| (s, "the training data is rendered at its starting value"))
                }
                crate::value::Dataset::Files { .. }
                | crate::value::Dataset::NerfSynthetic { .. }
                | crate::value::Dataset::Capture(_)
                | crate::value::Dataset::Points { .. } => None,
            }),
        };
        if let Some((span, what)) = untrained {
            self.diags.push(
                Diag::new(codes::UNTRAINED_PARAM, span, "this `param` is not trained here")
                    .label(what)
                    .help("`param(...)` is fitted only inside a `train` statement's `model`; write the number itself here"),
            );
        }
        let name_span = b.name.as_ref().map_or(b.kind.span, |n| n.span);
        let mut found =
            crate::outputs::check_job(program, kind, &mut self.files, &field, name_span);
        // A job with errors holds placeholders: only its outputs are
        // checked (against the others'); its cost and reach are not.
        if failed {
            self.diags.diags.extend(found);
            return;
        }
        use crate::work;
        let span = b
            .name
            .as_ref()
            .map_or(b.kind.span, |n| b.kind.span.to(n.span));
        let default_far;
        let (w, what, scene, reach) = match kind {
            StatementKind::Train => {
                let j = program.trains.last().expect("just added");
                let w = work::train_work(j, None);
                let scene = j.model.as_sdf().map(|f| f.shape.clone());
                (w, "iterations or rays", scene, None)
            }
            StatementKind::Volume => {
                let j = program.volumes.last().expect("just added");
                let reach = (
                    &j.cameras,
                    j.sampler.near,
                    j.sampler.far,
                    (field("sampler"), "the sampler's `far` ends the rays"),
                );
                (
                    work::volume_work(j, None),
                    "samples",
                    j.field.as_sdf().map(|f| f.shape.clone()),
                    Some(reach),
                )
            }
            StatementKind::Render => {
                let j = program.renders.last().expect("just added");
                let scene_size = self.sizes.shape(&j.scene, 0);
                default_far = format!("`far` is {} unless given", fmt_num(j.far));
                let far_note = if field("far") == b.kind.span {
                    (b.kind.span, default_far.as_str())
                } else {
                    (field("far"), "rays end here")
                };
                let reach = (&j.cameras, j.near, j.far, far_note);
                let w = work::render_work_of(j, None, &scene_size);
                (w, "iterations", Some(j.scene.clone()), Some(reach))
            }
        };
        found.extend(work::refuse(w, span, what));
        let size = scene
            .as_ref()
            .map_or(Size::SCALAR, |s| self.sizes.shape(s, 0));
        // Bounds are an expanded walk: worth it for a warning only on
        // scenes of ordinary size. (A neural field has no bounds to check.)
        if let (Some((cameras, near, far, note)), Some(scene)) =
            (reach.filter(|_| size.nodes <= 1_000_000), &scene)
        {
            found.extend(work::reach_warning(
                scene.bounds(),
                cameras,
                near,
                far,
                field("camera"),
                note,
            ));
        }
        // Totals over the file: each statement runs, one after another.
        self.total_evaluations += w.expected;
        self.total_primitives = self.total_primitives.saturating_add(size.primitives);
        if found.is_empty() && !self.total_refused {
            let refused = work::refuse_total(self.total_evaluations, self.total_primitives, span);
            // Once: every later statement is over too.
            self.total_refused = refused.is_some();
            found.extend(refused);
        }
        for d in found {
            self.diags.push(d);
        }
    }
}
