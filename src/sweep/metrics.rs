//! What a setting's run reports that settings are compared by, as typed
//! fields of its row: held-out PSNR and SSIM, and the Chamfer distances of
//! its mesh and of its field.
//!
//! They are read from the statements' JSON reports when the setting
//! finishes and kept in the row, so the table does not depend on the shape
//! of a report. A report writes a non-finite number as `null` (JSON has no
//! NaN): a measure reported as `null` is kept as not finite, never dropped
//! and never zero. In the row file a non-finite value is written as
//! `"NaN"`, `"inf"` or `"-inf"`.

use serde::{Deserialize, Serialize};

/// What a mesh's Chamfer distance was measured against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum ChamferReference {
    /// The true surface of a scene sdfl rendered the data from.
    TrueSurface,
    /// The data's points (a fit to a point cloud).
    DataPoints,
}

impl ChamferReference {
    /// As a training report names it (`mesh_fit.against`).
    fn from_report(against: &str) -> Option<ChamferReference> {
        match against {
            "true surface" => Some(ChamferReference::TrueSurface),
            "data" => Some(ChamferReference::DataPoints),
            _ => None,
        }
    }

    fn words(self) -> &'static str {
        match self {
            ChamferReference::TrueSurface => "the true surface",
            ChamferReference::DataPoints => "the data's points",
        }
    }
}

/// A setting's measures, each the mean over the run's training statements
/// that report it; absent where none does.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub(super) struct Metrics {
    /// Held-out PSNR at the last evaluation (dB).
    #[serde(default, skip_serializing_if = "Option::is_none", with = "reading")]
    pub held_out_psnr_db: Option<f64>,
    /// Held-out SSIM at the last evaluation (0 to 1).
    #[serde(default, skip_serializing_if = "Option::is_none", with = "reading")]
    pub held_out_ssim: Option<f64>,
    /// Symmetric Chamfer distance of the first mesh written after training
    /// (scene units); infinite for an empty mesh.
    #[serde(default, skip_serializing_if = "Option::is_none", with = "reading")]
    pub mesh_chamfer: Option<f64>,
    /// What every statement's mesh was measured against (absent when they
    /// differ).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_chamfer_to: Option<ChamferReference>,
    /// Symmetric Chamfer distance between the trained distance field's
    /// surface samples and the data's points (scene units).
    #[serde(default, skip_serializing_if = "Option::is_none", with = "reading")]
    pub field_chamfer: Option<f64>,
}

/// One of [`Metrics`]' measures: its column, its plot and how to read it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Metric {
    /// [`Metrics::held_out_psnr_db`].
    HeldOutPsnr,
    /// [`Metrics::held_out_ssim`].
    HeldOutSsim,
    /// [`Metrics::mesh_chamfer`].
    MeshChamfer,
    /// [`Metrics::field_chamfer`].
    FieldChamfer,
}

impl Metric {
    /// Every measure, in the order of the table's columns and the plot's
    /// panels.
    pub const ALL: [Metric; 4] = [
        Metric::HeldOutPsnr,
        Metric::HeldOutSsim,
        Metric::MeshChamfer,
        Metric::FieldChamfer,
    ];

    /// Its value in `m`.
    pub fn of(self, m: &Metrics) -> Option<f64> {
        match self {
            Metric::HeldOutPsnr => m.held_out_psnr_db,
            Metric::HeldOutSsim => m.held_out_ssim,
            Metric::MeshChamfer => m.mesh_chamfer,
            Metric::FieldChamfer => m.field_chamfer,
        }
    }

    /// The CSV column's name (its unit as a suffix where it has one; the
    /// Chamfer distances are in scene units).
    pub fn csv_name(self) -> &'static str {
        match self {
            Metric::HeldOutPsnr => "held_out_psnr_db",
            Metric::HeldOutSsim => "held_out_ssim",
            Metric::MeshChamfer => "mesh_chamfer",
            Metric::FieldChamfer => "field_chamfer",
        }
    }

    /// Its short name, for a plot's title.
    pub fn name(self, to: Option<ChamferReference>) -> String {
        match self {
            Metric::HeldOutPsnr => "held-out PSNR".into(),
            Metric::HeldOutSsim => "held-out SSIM".into(),
            Metric::MeshChamfer => match to {
                Some(to) => format!("mesh Chamfer to {}", to.words()),
                None => "mesh Chamfer".into(),
            },
            Metric::FieldChamfer => "field Chamfer to the data's points".into(),
        }
    }

    /// Its unit, for a column's or an axis' title.
    pub fn unit(self) -> &'static str {
        match self {
            Metric::HeldOutPsnr => "dB",
            Metric::HeldOutSsim => "0 to 1",
            Metric::MeshChamfer | Metric::FieldChamfer => "scene units",
        }
    }

    /// Whether it measures an error (a distance: lower is better).
    pub fn is_distance(self) -> bool {
        matches!(self, Metric::MeshChamfer | Metric::FieldChamfer)
    }

    /// A table cell: the value to a precision that tells settings apart,
    /// or what a non-finite value means.
    pub fn cell(self, x: f64) -> String {
        if x.is_finite() {
            match self {
                Metric::HeldOutPsnr => format!("{x:.2}"),
                Metric::HeldOutSsim => format!("{x:.4}"),
                // Three significant digits: 0.0193, 0.00512.
                Metric::MeshChamfer | Metric::FieldChamfer => {
                    let decimals = if x == 0.0 {
                        4
                    } else {
                        (2 - x.abs().log10().floor() as i32).clamp(0, 12) as usize
                    };
                    format!("{x:.decimals$}")
                }
            }
        } else if self.is_distance() && x == f64::INFINITY {
            "∞ (no surface)".into()
        } else {
            "not finite".into()
        }
    }
}

impl Metrics {
    /// The measures a run's statement reports (`sdfl run --json`'s
    /// `report`s) give.
    pub fn of_reports(reports: &[serde_json::Value]) -> Metrics {
        // A reported measure: a number, or `null` for a non-finite one
        // (`if_null`: what a `null` stands for); a key not there, none.
        let number = |v: Option<&serde_json::Value>, if_null: f64| match v? {
            serde_json::Value::Null => Some(if_null),
            v => v.as_f64(),
        };
        let last_held_out = |key: &str| {
            mean(reports.iter().filter_map(|r| {
                let last = r["held_out"].as_array()?.last()?;
                number(last.get(key), f64::NAN)
            }))
        };
        let fits = |key: &'static str| reports.iter().filter(move |r| r[key].is_object());
        // An empty mesh or a field with no surface found has no finite
        // distance (reported as `null`): infinity.
        let mesh_chamfer = mean(
            fits("mesh_fit").filter_map(|r| number(r["mesh_fit"].get("chamfer"), f64::INFINITY)),
        );
        let against: Vec<Option<ChamferReference>> = fits("mesh_fit")
            .map(|r| {
                r["mesh_fit"]["against"]
                    .as_str()
                    .and_then(ChamferReference::from_report)
            })
            .collect();
        let mesh_chamfer_to = against
            .first()
            .copied()
            .flatten()
            .filter(|first| against.iter().all(|a| *a == Some(*first)));
        Metrics {
            held_out_psnr_db: last_held_out("psnr"),
            held_out_ssim: last_held_out("ssim"),
            mesh_chamfer,
            mesh_chamfer_to,
            field_chamfer: mean(
                fits("fit").filter_map(|r| number(r["fit"].get("chamfer"), f64::INFINITY)),
            ),
        }
    }
}

/// The mean of `values`; none for none.
fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// An optional measure in a row file: a number, or `"NaN"`, `"inf"`,
/// `"-inf"` for a non-finite one (which JSON numbers cannot hold).
mod reading {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize, Deserialize)]
    #[serde(untagged)]
    enum Written {
        Number(f64),
        Text(String),
    }

    pub fn serialize<S: Serializer>(v: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
        match v {
            None => s.serialize_none(),
            Some(x) if x.is_finite() => s.serialize_some(x),
            Some(x) if x.is_nan() => s.serialize_some("NaN"),
            Some(x) if *x > 0.0 => s.serialize_some("inf"),
            Some(_) => s.serialize_some("-inf"),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
        match Option::<Written>::deserialize(d)? {
            None => Ok(None),
            Some(Written::Number(x)) => Ok(Some(x)),
            Some(Written::Text(t)) => match t.as_str() {
                "NaN" => Ok(Some(f64::NAN)),
                "inf" => Ok(Some(f64::INFINITY)),
                "-inf" => Ok(Some(f64::NEG_INFINITY)),
                _ => Err(serde::de::Error::custom(format!(
                    "`{t}` is not a measure (a number, \"NaN\", \"inf\" or \"-inf\")"
                ))),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// A NeuS-like training report: held-out evaluations and a mesh
    /// measured against the true surface.
    fn neus_report(psnr: serde_json::Value, chamfer: serde_json::Value) -> serde_json::Value {
        json!({
            "iterations": 400,
            "final_loss": 0.01,
            "held_out": [
                {"step": 200, "seconds": 1.0, "psnr": 20.0, "ssim": 0.7},
                {"step": 400, "seconds": 2.0, "psnr": psnr, "ssim": 0.875},
            ],
            "mesh_fit": {"chamfer": chamfer, "points_to_mesh": 0.01, "mesh_to_points": 0.02,
                         "against": "true surface", "points": 1000, "samples": 1000},
            "written": [{"path": "fit.ply", "kind": "mesh"}],
        })
    }

    #[test]
    fn a_training_report_gives_held_out_psnr_ssim_and_chamfer() {
        let m = Metrics::of_reports(&[neus_report(json!(27.5), json!(0.0125))]);
        assert_eq!(m.held_out_psnr_db, Some(27.5), "the last evaluation");
        assert_eq!(m.held_out_ssim, Some(0.875));
        assert_eq!(m.mesh_chamfer, Some(0.0125));
        assert_eq!(m.mesh_chamfer_to, Some(ChamferReference::TrueSurface));
        assert_eq!(m.field_chamfer, None);
        // Two training statements: the mean; meshes against different
        // references name none.
        let mut data = neus_report(json!(30.5), json!(0.0375));
        data["mesh_fit"]["against"] = json!("data");
        let m = Metrics::of_reports(&[neus_report(json!(27.5), json!(0.0125)), data]);
        assert_eq!(m.held_out_psnr_db, Some(29.0));
        assert_eq!(m.mesh_chamfer, Some(0.025));
        assert_eq!(m.mesh_chamfer_to, None);
        // A render's report has none of them.
        let render = json!({"views": 1, "written": [{"path": "v.png", "kind": "image"}]});
        assert_eq!(Metrics::of_reports(&[render]), Metrics::default());
        // A fit to points reports the field's Chamfer distance.
        let fit = json!({"fit": {"surface_mean_abs": 0.001, "eikonal": 0.01, "chamfer": 0.004,
                                 "surface_samples": 100}});
        assert_eq!(Metrics::of_reports(&[fit]).field_chamfer, Some(0.004));
        // A key not reported is absent, not a non-finite value.
        let mut partial = neus_report(json!(27.5), json!(0.0125));
        partial["mesh_fit"]
            .as_object_mut()
            .unwrap()
            .remove("chamfer");
        for e in partial["held_out"].as_array_mut().unwrap() {
            e.as_object_mut().unwrap().remove("ssim");
        }
        let m = Metrics::of_reports(&[partial]);
        assert_eq!((m.held_out_ssim, m.mesh_chamfer), (None, None));
        assert_eq!(m.held_out_psnr_db, Some(27.5));
    }

    #[test]
    fn a_diverged_run_is_not_finite_never_absent_or_zero() {
        // A report writes NaN and ∞ as `null`.
        let m = Metrics::of_reports(&[neus_report(json!(null), json!(null))]);
        assert!(m.held_out_psnr_db.is_some_and(f64::is_nan), "{m:?}");
        assert_eq!(m.mesh_chamfer, Some(f64::INFINITY), "an empty mesh");
        assert_eq!(Metric::HeldOutPsnr.cell(f64::NAN), "not finite");
        assert_eq!(Metric::MeshChamfer.cell(f64::INFINITY), "∞ (no surface)");
        assert_eq!(Metric::MeshChamfer.cell(f64::NAN), "not finite");
        // And they survive the row file.
        let json = serde_json::to_string(&m).unwrap();
        assert!(json.contains(r#""held_out_psnr_db":"NaN""#), "{json}");
        assert!(json.contains(r#""mesh_chamfer":"inf""#), "{json}");
        let back: Metrics = serde_json::from_str(&json).unwrap();
        assert!(back.held_out_psnr_db.is_some_and(f64::is_nan));
        assert_eq!(back.mesh_chamfer, Some(f64::INFINITY));
        let neg: Metrics = serde_json::from_str(r#"{"held_out_ssim":"-inf"}"#).unwrap();
        assert_eq!(neg.held_out_ssim, Some(f64::NEG_INFINITY));
        assert!(serde_json::from_str::<Metrics>(r#"{"mesh_chamfer":"lots"}"#).is_err());
    }

    #[test]
    fn metrics_round_trip_and_absent_ones_stay_absent() {
        let m = Metrics {
            held_out_psnr_db: Some(31.25),
            held_out_ssim: Some(0.9),
            mesh_chamfer: Some(0.0071),
            mesh_chamfer_to: Some(ChamferReference::TrueSurface),
            field_chamfer: None,
        };
        let json = serde_json::to_string(&m).unwrap();
        assert!(
            !json.contains("field_chamfer"),
            "absent is left out: {json}"
        );
        assert_eq!(serde_json::from_str::<Metrics>(&json).unwrap(), m);
        assert_eq!(
            serde_json::from_str::<Metrics>("{}").unwrap(),
            Metrics::default()
        );
    }

    #[test]
    fn cells_tell_settings_apart() {
        assert_eq!(Metric::MeshChamfer.cell(0.0193), "0.0193");
        assert_eq!(Metric::MeshChamfer.cell(0.005123), "0.00512");
        assert_eq!(Metric::MeshChamfer.cell(0.25), "0.250");
        assert_eq!(Metric::MeshChamfer.cell(12.5), "12.5");
        assert_eq!(Metric::MeshChamfer.cell(0.0), "0.0000");
        assert_eq!(Metric::HeldOutPsnr.cell(29.256), "29.26");
        assert_eq!(Metric::HeldOutSsim.cell(0.91234), "0.9123");
    }
}
