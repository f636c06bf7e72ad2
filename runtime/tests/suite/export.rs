//! Exports from a radiance field: density meshes at their level, the data
//! frame, depths, point clouds and their crop, PLY sizes, hostile fields.

mod depth;
mod normals;

use glam::{DAffine3, DVec3};
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::{DensityKind, LastInterval};

use sdfl_runtime::export::depth::depth_values;
use sdfl_runtime::export::*;
use sdfl_runtime::mesh::MeshGrid;
use sdfl_runtime::volume::{DensityModel, ImageSize, Stratified};

const R: f32 = 0.6;
const COLOUR: [f32; 3] = [0.2, 0.6, 0.9];

/// A sphere of radius `R` at the origin, one colour, sharp VolSDF density.
fn sphere(alpha: f32, beta: f32) -> Analytic<impl Fn([f32; 3]) -> (f32, [f32; 3]) + Sync> {
    Analytic {
        field: |p: [f32; 3]| {
            let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - R;
            (d, COLOUR)
        },
        model: DensityModel {
            kind: DensityKind::VolSdf,
            alpha,
            beta,
            last_interval: LastInterval::Infinite,
        },
    }
}

fn cameras() -> Vec<(Camera, ImageSize)> {
    [
        [0.0, 0.0, 3.0],
        [3.0, 1.0, 0.0],
        [-2.0, 2.0, -1.0],
        [0.5, -3.0, 0.5],
    ]
    .into_iter()
    .map(|e| {
        (
            Camera::look_at(DVec3::from(e), DVec3::ZERO, DVec3::Y, 4.0),
            ImageSize {
                width: 24,
                height: 16,
            },
        )
    })
    .collect()
}

#[test]
fn a_density_mesh_of_a_sphere_lies_at_its_level() {
    let f = sphere(50.0, 0.02);
    // σ(d = 0) = α/2, and σ falls with d: the level α/2 is the sphere.
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 48);
    let m = density_mesh(&f, 25.0, &grid, 1 << 20, &DAffine3::IDENTITY).unwrap();
    assert!(m.mesh.vertices.len() > 1000);
    assert_eq!(m.colours.len(), m.mesh.vertices.len());
    for (v, n) in m.mesh.vertices.iter().zip(&m.mesh.normals) {
        let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        assert!((r - R).abs() < 2e-3, "vertex at radius {r}");
        // Normals point out, towards lower density.
        let dot = (v[0] * n[0] + v[1] * n[1] + v[2] * n[2]) / r;
        assert!(dot > 0.95, "normal {n:?} at {v:?}");
    }
    let want = COLOUR.map(|c| (c * 255.0).round() as u8);
    assert!(m.colours.iter().all(|c| *c == want));
    // A level above the peak density (α) has no surface.
    let none = density_mesh(&f, 60.0, &grid, 1 << 20, &DAffine3::IDENTITY).unwrap();
    assert!(none.mesh.vertices.is_empty());
    // A higher level lies inside: σ = α(1 − e^{d/β}/2) = 0.75α at d = −β ln 2.
    let inner = density_mesh(&f, 37.5, &grid, 1 << 20, &DAffine3::IDENTITY).unwrap();
    let want_r = R - 0.02 * std::f32::consts::LN_2;
    for v in &inner.mesh.vertices {
        let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        // The density is far from linear across a cell (β is half a
        // cell): one Newton step leaves a tenth of a cell.
        assert!(
            (r - want_r).abs() < 4e-3,
            "vertex at radius {r}, want {want_r}"
        );
    }
}

#[test]
fn the_data_frame_transform_moves_vertices_and_normals() {
    let f = sphere(50.0, 0.02);
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 24);
    let to_data = DAffine3::from_scale_rotation_translation(
        DVec3::splat(2.0),
        glam::DQuat::from_rotation_y(0.7),
        DVec3::new(1.0, -2.0, 3.0),
    );
    let m = density_mesh(&f, 25.0, &grid, 1 << 20, &to_data).unwrap();
    let c = DVec3::new(1.0, -2.0, 3.0);
    for (v, n) in m.mesh.vertices.iter().zip(&m.mesh.normals) {
        let p = DVec3::from(v.map(f64::from)) - c;
        assert!((p.length() - 2.0 * R as f64).abs() < 6e-3, "{p}");
        let n = DVec3::from(n.map(f64::from));
        assert!(n.dot(p.normalize()) > 0.95);
    }
}

/// The f64 reference of one ray's ends: densities of the sphere at the
/// stratified depths, weights, `Σwt` and `Σw`.
fn reference_end(origin: DVec3, dir: DVec3, s: &Stratified, alpha: f64, beta: f64) -> (f64, f64) {
    let t: Vec<f64> = s.depths().iter().map(|&t| t as f64).collect();
    let (mut trans, mut depth, mut acc) = (1.0, 0.0, 0.0);
    for k in 0..t.len() {
        let delta = if k + 1 < t.len() {
            t[k + 1] - t[k]
        } else {
            1e10
        };
        let d = (origin + dir * t[k]).length() - R as f64;
        let sigma = if d > 0.0 {
            0.5 * alpha * (-d / beta).exp()
        } else {
            alpha * (1.0 - 0.5 * (d / beta).exp())
        };
        let w = trans * (1.0 - (-sigma * delta).exp());
        depth += w * t[k];
        acc += w;
        trans *= (-sigma * delta).exp();
    }
    (depth, acc)
}

#[test]
fn depth_is_the_expected_depth_over_the_opacity() {
    let (alpha, beta) = (20.0, 0.05);
    let f = sphere(alpha, beta);
    let s = Stratified::new(128, 1.0, 5.0).unwrap();
    let (cam, size) = cameras()[0];
    let ends = render_ends(&f, &cam, size, &s, LastInterval::Infinite).unwrap();
    let d = depth_values(&ends, 0.5);
    let (mut hits, mut misses) = (0, 0);
    for (p, (e, d)) in ends.iter().zip(&d).enumerate() {
        let r = sdfl_runtime::volume::rays::pixel_ray(&cam, size, 0, p as u32);
        let (o, dir) = (
            DVec3::from(r.origin.map(f64::from)),
            DVec3::from(r.dir.map(f64::from)),
        );
        let (want_depth, want_acc) = reference_end(o, dir, &s, alpha as f64, beta as f64);
        assert!(
            (e.opacity as f64 - want_acc).abs() < 1e-4,
            "{} vs {want_acc}",
            e.opacity
        );
        assert!((e.depth as f64 - want_depth).abs() < 1e-3 * want_depth.max(1.0));
        if want_acc >= 0.5 {
            hits += 1;
            let want = want_depth / want_acc;
            assert!((*d as f64 - want).abs() < 1e-3 * want, "{d} vs {want}");
            // And near the true hit where the ray meets the sphere head
            // on (the density's bias is about β; grazing rays gather
            // density along the surface before it).
            let b = o.dot(dir);
            let miss = (o.length_squared() - b * b).max(0.0).sqrt();
            if miss < 0.5 * R as f64 {
                let hit = -b - ((R * R) as f64 - miss * miss).sqrt();
                assert!(
                    (*d as f64 - hit).abs() < 2.0 * beta as f64,
                    "{d} vs hit {hit}"
                );
            }
        } else {
            misses += 1;
            assert!(d.is_nan());
        }
    }
    assert!(hits > 20 && misses > 20, "{hits} hits, {misses} misses");
}

/// Raw depth is written in the data's units: a field trained in a frame
/// scaled by 1/4 (moved and turned too) gives depths 4 times its own,
/// NaN where nothing was hit; without a normalisation, the same bits.
#[test]
fn raw_depth_is_in_the_datas_units() {
    use sdfl_stdlib::value::{Output, OutputKind, Sampler};
    let f = sphere(20.0, 0.05);
    let dir = tempfile::tempdir().unwrap();
    let (cam, size) = cameras()[0];
    let sampler = Sampler {
        samples: 64,
        near: 1.0,
        far: 5.0,
        jitter: false,
        last_interval: LastInterval::Infinite,
    };
    let out = [Output {
        kind: OutputKind::RawDepth { min_opacity: 0.5 },
        path: "d.npy".into(),
        span: Default::default(),
    }];
    let depths = |to_data: DAffine3| {
        let cx = write::ExportContext {
            out_dir: dir.path(),
            sampler: &sampler,
            cameras: &[cam],
            size: (size.width, size.height),
            ray_views: &[],
            auto_region: None,
            object_region: None,
            seed: 1,
            to_data,
            status: &|_| {},
            ray_ends: None,
        };
        write::write_field_exports(&f, &out, &cx).unwrap();
        let bytes = std::fs::read(dir.path().join("d.npy")).unwrap();
        sdfl_runtime::data::npy::parse_f32(&bytes).unwrap().data
    };
    let own = depths(DAffine3::IDENTITY);
    let ends = render_ends(
        &f,
        &cam,
        size,
        &Stratified::new(64, 1.0, 5.0).unwrap(),
        LastInterval::Infinite,
    )
    .unwrap();
    let raw = depth_values(&ends, 0.5);
    assert_eq!(
        own.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
        raw.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
    );
    let scaled = depths(DAffine3::from_scale_rotation_translation(
        DVec3::splat(4.0),
        glam::DQuat::from_rotation_y(0.8),
        DVec3::new(10.0, -3.0, 2.0),
    ));
    assert!(own.iter().any(|d| d.is_finite()) && own.iter().any(|d| d.is_nan()));
    for (a, b) in own.iter().zip(&scaled) {
        assert!(a.is_nan() == b.is_nan(), "{a} vs {b}");
        if a.is_finite() {
            assert!((b - 4.0 * a).abs() <= 1e-6 * b.abs(), "{b} vs 4 × {a}");
        }
    }
}

#[test]
fn point_cloud_points_lie_on_the_surface_with_its_colour() {
    let f = sphere(200.0, 0.005);
    let s = Stratified::new(512, 1.0, 5.0).unwrap();
    let views = cameras();
    let cloud_of = |field: &dyn RadianceField, count: usize, min_opacity: f32, seed: u64| {
        let settings = CloudSettings {
            count,
            min_opacity,
            rays_per_point: 4,
            crop: Crop::None,
            seed,
        };
        let last = LastInterval::Infinite;
        point_cloud(field, &views, settings, &s, last, &DAffine3::IDENTITY).unwrap()
    };
    let cloud = cloud_of(&f, 500, 0.9, 7);
    assert_eq!(cloud.points.len(), 500);
    assert!(cloud.rays >= 500);
    let want = COLOUR.map(|c| (c * 255.0).round() as u8);
    for ((p, c), n) in cloud.points.iter().zip(&cloud.colours).zip(&cloud.normals) {
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        assert!((r - R).abs() < 0.02, "point at radius {r}");
        // The sphere's outward normal, from the neighbouring points.
        let along = (0..3).map(|a| n[a] * p[a] / r).sum::<f32>();
        assert!(along > 0.95, "normal {n:?} at {p:?}");
        assert!(
            c.iter().zip(&want).all(|(a, b)| a.abs_diff(*b) <= 1),
            "{c:?}"
        );
    }
    // Seeded: the same cloud again.
    let again = cloud_of(&f, 500, 0.9, 7);
    assert_eq!(cloud, again);
    // An empty field keeps nothing and stops after its ray budget.
    let empty = Analytic {
        field: |_: [f32; 3]| (10.0f32, COLOUR),
        model: f.model,
    };
    let none = cloud_of(&empty, 100, 0.5, 1);
    assert!(none.points.is_empty());
    assert_eq!(none.rays, 400);
}

#[test]
fn hostile_fields_give_finite_exports() {
    // NaN and infinite densities and colours count as empty space.
    let bad = Analytic {
        field: |p: [f32; 3]| {
            if p[0] > 0.0 {
                (f32::NAN, [f32::NAN; 3])
            } else {
                (f32::NEG_INFINITY, [f32::INFINITY; 3])
            }
        },
        model: sphere(50.0, 0.02).model,
    };
    let s = Stratified::new(32, 1.0, 5.0).unwrap();
    let (cam, size) = cameras()[0];
    let ends = render_ends(&bad, &cam, size, &s, LastInterval::Infinite).unwrap();
    for e in &ends {
        assert!(e.opacity.is_finite() && e.depth.is_finite());
    }
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 16);
    let m = density_mesh(&bad, 1.0, &grid, 1 << 20, &DAffine3::IDENTITY).unwrap();
    assert!(m.mesh.vertices.iter().flatten().all(|x| x.is_finite()));
}

#[test]
fn ply_files_have_the_declared_sizes() {
    let f = sphere(50.0, 0.02);
    let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], 16);
    let m = density_mesh(&f, 25.0, &grid, 1 << 20, &DAffine3::IDENTITY).unwrap();
    let b = ply::mesh_bytes(&m);
    let end = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = std::str::from_utf8(&b[..end]).unwrap();
    assert!(header.contains(&format!("element vertex {}", m.mesh.vertices.len())));
    assert!(header.contains("property uchar red"));
    assert_eq!(
        b.len() - end,
        m.mesh.vertices.len() * 27 + m.mesh.triangles.len() * 13
    );
    let cloud = Cloud {
        points: vec![[1.0, 2.0, 3.0]],
        normals: vec![[0.0, 0.6, 0.8]],
        colours: vec![[4, 5, 6]],
        rays: 1,
    };
    let b = ply::cloud_bytes(&cloud);
    assert!(b.ends_with(&[4, 5, 6]));
    assert_eq!(&b[b.len() - 27..b.len() - 23], &1.0f32.to_le_bytes());
    assert_eq!(&b[b.len() - 11..b.len() - 7], &0.6f32.to_le_bytes());
    let end = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    assert_eq!(b.len() - end, 27);
}

/// A crop keeps only the points inside its box: in the field's frame, or
/// in the data's (here twice the field's, moved by 1 along x).
#[test]
fn point_clouds_keep_only_the_points_in_their_crop() {
    let f = sphere(200.0, 0.005);
    let s = Stratified::new(512, 1.0, 5.0).unwrap();
    let views = cameras();
    let to_data = DAffine3::from_scale_rotation_translation(
        DVec3::splat(2.0),
        glam::DQuat::IDENTITY,
        DVec3::new(1.0, 0.0, 0.0),
    );
    let cloud = |crop| {
        point_cloud(
            &f,
            &views,
            CloudSettings {
                count: 300,
                min_opacity: 0.9,
                rays_per_point: 8,
                crop,
                seed: 3,
            },
            &s,
            LastInterval::Infinite,
            &to_data,
        )
        .unwrap()
    };
    // The upper half of the sphere (y ≥ 0), in either frame.
    let field = cloud(Crop::Field {
        min: [-2.0, 0.0, -2.0],
        max: [2.0, 2.0, 2.0],
    });
    let data = cloud(Crop::Data {
        min: [-3.0, 0.0, -4.0],
        max: [5.0, 4.0, 4.0],
    });
    for c in [&field, &data] {
        assert_eq!(c.points.len(), 300);
        assert_eq!(c.normals.len(), 300);
        assert!(c.points.iter().all(|p| p[1] >= 0.0), "a point below y = 0");
    }
    assert_eq!(field, data);
    // Without a crop, points fall on both halves.
    let all = cloud(Crop::None);
    assert!(all.points.iter().any(|p| p[1] < -0.1) && all.points.iter().any(|p| p[1] > 0.1));
    // A box nothing reaches keeps no point, within the ray budget.
    let none = cloud(Crop::Field {
        min: [5.0; 3],
        max: [6.0; 3],
    });
    assert!(none.points.is_empty() && none.normals.is_empty());
    assert_eq!(none.rays, 300 * 8);
}

/// Each vertex's index once vertices are welded by position (one index
/// per distinct position, bit for bit, as `trimesh.merge_vertices` does).
fn welded_by_position(vertices: &[[f32; 3]]) -> Vec<u32> {
    let mut index: std::collections::HashMap<[u32; 3], u32> = Default::default();
    vertices
        .iter()
        .map(|v| {
            let n = index.len() as u32;
            *index.entry(v.map(f32::to_bits)).or_insert(n)
        })
        .collect()
}

/// How many triangles hold each edge, vertices renamed by `id`.
fn edge_uses(triangles: &[[u32; 3]], id: &[u32]) -> std::collections::HashMap<(u32, u32), u32> {
    let mut edges = std::collections::HashMap::new();
    for t in triangles {
        let t = t.map(|i| id[i as usize]);
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    edges
}

/// A density mesh cut by its grid's box (a world that runs on past the
/// bounds, as a capture's floor does) is open there, and every edge is in
/// at most two triangles, welded by position too. Beside the box a face
/// crossed twice could have three of its four quads, and the edge they
/// share was in three triangles: README's capture recipe's mesh had 100
/// such edges, 99 of them on its cut, and these rough balls larger than
/// the box had 2 to 54.
#[test]
fn a_density_mesh_cut_by_its_box_has_no_edge_in_three_triangles() {
    for (freq, amp, res) in [(17.0f32, 0.3f32, 16), (31.0, 0.15, 48), (53.0, 0.15, 24)] {
        let cut = Analytic {
            field: move |p: [f32; 3]| {
                let [x, y, z] = p;
                let r = (x * x + y * y + z * z).sqrt();
                let ripple =
                    amp * (freq * x).sin() * (0.77 * freq * y).sin() * (1.3 * freq * z).sin()
                        + amp * (1.7 * freq * x + 0.5 * freq * z).cos();
                (r - 1.3 + ripple, COLOUR)
            },
            model: DensityModel {
                kind: DensityKind::VolSdf,
                alpha: 50.0,
                beta: 0.02,
                last_interval: LastInterval::Infinite,
            },
        };
        let what = format!("frequency {freq}, amplitude {amp}, {res} cells");
        let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], res);
        let m = density_mesh(&cut, 25.0, &grid, 1 << 22, &DAffine3::IDENTITY).unwrap();
        assert!(m.mesh.triangles.len() > 1000, "{what}");
        let welded = welded_by_position(&m.mesh.vertices);
        let written: Vec<u32> = (0..m.mesh.vertices.len() as u32).collect();
        for (how, id) in [("as written", &written), ("welded", &welded)] {
            let edges = edge_uses(&m.mesh.triangles, id);
            let open = edges.values().filter(|&&n| n == 1).count();
            let bad = edges.values().filter(|&&n| n > 2).count();
            assert!(open > 0, "{what}, {how}: the cut leaves no open edge");
            assert_eq!(
                bad, 0,
                "{what}, {how}: {bad} edges in more than two triangles"
            );
        }
    }
}

/// A density mesh stays a closed 2-manifold once its vertices are welded
/// by position (as `trimesh.merge_vertices` or MeshLab does before a
/// watertightness check): a capture's mesh had 10 edges in more than two
/// triangles after welding. Here a field as rough as a trained NeRF's (a
/// blob with ripples of a few cells, thin walls and saddles), at a grid
/// fine enough to resolve them and at one too coarse to.
#[test]
fn a_density_mesh_welded_by_position_is_two_manifold() {
    let rough = Analytic {
        field: |p: [f32; 3]| {
            let [x, y, z] = p;
            let r = (x * x + y * y + z * z).sqrt();
            let ripple = 0.09 * (17.0 * x).sin() * (13.0 * y).sin() * (11.0 * z).sin()
                + 0.05 * (29.0 * x + 23.0 * z).sin() * (31.0 * y).cos();
            (r - 0.6 + ripple, COLOUR)
        },
        model: DensityModel {
            kind: DensityKind::VolSdf,
            alpha: 50.0,
            beta: 0.02,
            last_interval: LastInterval::Infinite,
        },
    };
    for res in [24, 48, 96] {
        let grid = MeshGrid::covering([-1.0; 3], [1.0; 3], res);
        let m = density_mesh(&rough, 25.0, &grid, 1 << 22, &DAffine3::IDENTITY).unwrap();
        assert!(
            m.mesh.triangles.len() > 500,
            "{res}: {}",
            m.mesh.triangles.len()
        );
        let welded = welded_by_position(&m.mesh.vertices);
        for t in &m.mesh.triangles {
            let t = t.map(|i| welded[i as usize]);
            assert!(
                t[0] != t[1] && t[1] != t[2] && t[0] != t[2],
                "{res}: a triangle collapses when welded"
            );
        }
        let edges = edge_uses(&m.mesh.triangles, &welded);
        let bad = edges.values().filter(|&&n| n != 2).count();
        assert_eq!(
            bad, 0,
            "{res}: {bad} edges not in exactly two triangles after welding"
        );
    }
}
