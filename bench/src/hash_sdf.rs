//! Hash-grid SDF step benchmark: `cargo run --release -p sdfl-bench --
//! hash-sdf [reps]`.
//!
//! One training step (forward, `∇f`, the loss's backward, and the sparse
//! Adam update of the touched table rows) of the hash-grid SDF on 4096
//! points (2048 on a sphere, 2048 in the box), with the exact eikonal term
//! and with Neuralangelo's central differences; and the same batch through
//! the existing harmonic-encoding SDF network's `loss_and_grad` (IGR's
//! 6 × 128) for comparison. Timed in turns so load falls on all alike.
//!
//! Then meshing: surface nets at 192 cells a side over the field of
//! `examples/neural_sdf_fast.sdfl`'s shape (16 levels of 2^16 rows, 16 to
//! 128 cells, one layer of 64; its tables given bumps), through the
//! blocked `distances` and through the point-at-a-time reference, in
//! turns; the two meshes must be the same bits.

use std::time::Instant;

use crate::stats::{load, median_min};
use sdfl_runtime::mesh::{surface_nets, DistanceField, Lipschitz, Mesh, MeshGrid};
use sdfl_runtime::neural::hash_sdf::{
    Eikonal, HashSdf, HashSdfField, HashSdfLoss, HashSdfSpec, HashSdfWork,
};
use sdfl_runtime::neural::hashgrid::Adam;
use sdfl_runtime::neural::hashgrid::HashGridConfig;
use sdfl_runtime::neural::sdf_net::{SdfLoss, SdfNet, SdfNetSpec, SdfWork};
use sdfl_runtime::volume::SplitMix64;

/// Prints step times of the three methods, `reps` turns each.
pub fn main(reps: usize) {
    let n = 2048;
    let mut rng = SplitMix64::new(7);
    let surface: Vec<[f32; 3]> = (0..n)
        .map(|_| {
            let v = [0, 1, 2].map(|_| 2.0 * rng.next_f32() - 1.0);
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-6);
            v.map(|x| 0.6 * x / l)
        })
        .collect();
    let random: Vec<[f32; 3]> = (0..n)
        .map(|_| [0, 1, 2].map(|_| 2.0 * rng.next_f32() - 1.0))
        .collect();
    let spec = HashSdfSpec::default();
    let net = HashSdf::new(&spec).expect("hash SDF");
    let mut params = net.init(1);
    let tables = net.table_params();
    let mut grad = vec![0.0; params.len()];
    let (mut m, mut v) = (vec![0.0; tables], vec![0.0; tables]);
    let mut touched = net.grid().touched_set();
    let mut work = HashSdfWork::default();
    let loss = HashSdfLoss::default();
    let mut step = 0u64;
    // Returns the ms of `loss_and_grad` alone.
    let mut hash_step = |eik: Eikonal| {
        // `loss_and_grad` adds; the sparse update below clears the tables'.
        grad[tables..].fill(0.0);
        let t = Instant::now();
        net.loss_and_grad(
            &params,
            &surface,
            &random,
            &loss,
            eik,
            net.levels(),
            &mut work,
            &mut grad,
            &mut touched,
        );
        let loss_ms = t.elapsed().as_secs_f64() * 1e3;
        step += 1;
        let (p, g) = (&mut params[..tables], &mut grad[..tables]);
        net.grid()
            .sparse_adam_update(p, g, &mut m, &mut v, &mut touched, step, Adam::default())
            .expect("adam");
        grad[tables..].fill(0.0);
        loss_ms
    };
    let mlp = SdfNet::new(&SdfNetSpec::default());
    let mlp_params = mlp.init_geometric(1, 0.5);
    let mut mlp_grad = vec![0.0; mlp.len];
    let mut mlp_work = SdfWork::default();
    let flat = |p: &[[f32; 3]]| p.iter().flatten().copied().collect::<Vec<f32>>();
    let (s_flat, r_flat) = (flat(&surface), flat(&random));
    let mut mlp_step = || {
        mlp.loss_and_grad(
            &mlp_params,
            &s_flat,
            &r_flat,
            &SdfLoss::default(),
            &mut mlp_work,
            &mut mlp_grad,
        );
    };
    let fd = Eikonal::FiniteDifference { step: 1.0 / 2048.0 };
    println!(
        "hash grid: {} levels × {} features, 2^{} rows, res {}..{}, {} × {} softplus MLP; {} params",
        spec.grid.levels,
        spec.grid.features,
        spec.grid.log2_table,
        spec.grid.min_res,
        spec.grid.max_res,
        spec.layers,
        spec.width,
        net.param_count()
    );
    println!(
        "load before: {}; threads {}",
        load(),
        rayon::current_num_threads()
    );
    // Warm-up (grows the workspaces).
    hash_step(Eikonal::Exact);
    hash_step(fd);
    mlp_step();
    let mut ms = [(); 5].map(|_| Vec::new());
    for _ in 0..reps {
        let t = Instant::now();
        ms[3].push(hash_step(Eikonal::Exact));
        ms[0].push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        ms[4].push(hash_step(fd));
        ms[1].push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        mlp_step();
        ms[2].push(t.elapsed().as_secs_f64() * 1e3);
    }
    let [exact, fdiff, igr, exact_loss, fd_loss] = ms.map(median_min);
    println!("| step of 4096 points | ms (median) | ms (min) | / hash exact (median) |");
    println!("|---|---:|---:|---:|");
    for (name, (med, min)) in [
        ("hash SDF, exact eikonal", exact),
        ("hash SDF, finite-difference eikonal", fdiff),
        ("harmonic MLP SDF 6 × 128 (sdf_net, no update)", igr),
        ("hash SDF, exact, loss_and_grad only", exact_loss),
        ("hash SDF, differences, loss_and_grad only", fd_loss),
    ] {
        println!("| {name} | {med:.2} | {min:.2} | {:.2} |", med / exact.0);
    }
    println!("load after: {}", load());
    mesh(reps.div_ceil(10).max(1));
}

/// The field through [`HashSdf::distances_pointwise`]: meshing as it was.
struct Pointwise<'a>(HashSdfField<'a>);

impl DistanceField for Pointwise<'_> {
    fn distances(&self, points: &[[f32; 3]], out: &mut [f32]) {
        let f = &self.0;
        f.net.distances_pointwise(f.params, points, f.active, out)
    }
    fn gradients(&self, points: &[[f32; 3]], h: f32, f: &mut [f32], g: &mut [[f32; 3]]) {
        self.0.gradients(points, h, f, g)
    }
}

/// Seconds to mesh `field` (claimed 2-Lipschitz, as a trained one is), and the mesh.
fn time_mesh<F: DistanceField>(field: F, grid: &MeshGrid) -> (f64, Mesh) {
    let t = Instant::now();
    let m = surface_nets(&Lipschitz(field, 2.0), grid, usize::MAX, &|_| {}).expect("mesh");
    (t.elapsed().as_secs_f64(), m)
}

/// Times meshing the example's field both ways, `turns` each.
fn mesh(turns: usize) {
    let spec = HashSdfSpec {
        grid: HashGridConfig {
            levels: 16,
            features: 2,
            log2_table: 16,
            min_res: 16,
            max_res: 128,
            bbox_min: [-1.2; 3],
            bbox_max: [1.2; 3],
        },
        ..HashSdfSpec::default()
    };
    let net = HashSdf::new(&spec).expect("hash SDF");
    let mut params = net.init(3);
    // Bumps of about a hundredth on the sphere (features of ±0.05).
    let mut rng = SplitMix64::new(4);
    for v in &mut params[..net.table_params()] {
        *v = (2.0 * rng.next_f32() - 1.0) * 0.05;
    }
    let field = || HashSdfField {
        net: &net,
        params: &params,
        active: net.levels(),
    };
    let grid = MeshGrid::covering([-0.8; 3], [0.8; 3], 192);
    // The distances alone, at every grid point of a plane's worth × 64.
    let plane: Vec<[f32; 3]> = (0..193 * 193 * 64)
        .map(|i| {
            let (a, b, c) = (i % 193, (i / 193) % 193, i / (193 * 193));
            [a, b, c].map(|v| -0.8 + 1.6 * v as f32 / 192.0)
        })
        .collect();
    let mut out = vec![0.0; plane.len()];
    let t = Instant::now();
    net.distances(&params, &plane, net.levels(), &mut out);
    let blocked_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    net.distances_pointwise(&params, &plane, net.levels(), &mut out);
    let pointwise_s = t.elapsed().as_secs_f64();
    println!(
        "distances at {} points: blocked {blocked_s:.2} s, point at a time {pointwise_s:.2} s ({:.2}×)",
        plane.len(),
        pointwise_s / blocked_s
    );
    println!("load before meshing: {}", load());
    let (mut blocked, mut pointwise) = (Vec::new(), Vec::new());
    let mut vertices = 0;
    for _ in 0..turns {
        let (t, a) = time_mesh(field(), &grid);
        blocked.push(t);
        let (t, b) = time_mesh(Pointwise(field()), &grid);
        pointwise.push(t);
        let bits = |m: &Mesh| {
            m.vertices
                .iter()
                .flatten()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        assert!(
            bits(&a) == bits(&b) && a.triangles == b.triangles,
            "the blocked pass gives the reference's mesh"
        );
        vertices = a.vertices.len();
    }
    let (b, p) = (median_min(blocked), median_min(pointwise));
    println!("| mesh, 192 cells a side ({vertices} vertices) | s (median) | s (min) | / blocked (median) |");
    println!("|---|---:|---:|---:|");
    println!("| blocked distances | {:.2} | {:.2} | 1.00 |", b.0, b.1);
    println!(
        "| point at a time (before) | {:.2} | {:.2} | {:.2} |",
        p.0,
        p.1,
        p.0 / b.0
    );
    println!("load after meshing: {}", load());
}
