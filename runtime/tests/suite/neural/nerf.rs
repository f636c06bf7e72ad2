//! The NeRF network: gradients against finite differences, the view
//! direction's branch, the assignment's size.

use sdfl_runtime::neural::mlp::Activation;
use sdfl_runtime::neural::nerf::*;
use sdfl_runtime::volume::SplitMix64;
use sdfl_stdlib::value::{DensityActivation, Encoding, Harmonic as Spec, HashGridSpec, Nerf};

pub(crate) fn spec(view_dependent: bool) -> Nerf {
    Nerf {
        position: Encoding::Harmonic(Spec {
            freqs: 3,
            include_input: true,
        }),
        direction: view_dependent.then_some(Encoding::Harmonic(Spec {
            freqs: 2,
            include_input: true,
        })),
        layers: 4,
        width: 16,
        skips: vec![2],
        color_width: 8,
        fine: 0,
        background: sdfl_stdlib::value::Background::Color([0.0; 3]),
        background_at: Default::default(),
        unbounded: None,
        seed: 0,
        density: DensityActivation::Relu,
        occupancy: None,
        precision: Default::default(),
    }
}

/// `Σ a·σ + Σ b·rgb` for fixed weights `a`, `b`, in f64 through the
/// f32 network (differences taken with a large enough step).
fn probe(net: &NerfNet, params: &[f32], points: &[f32], dirs: &[f32], a: &[f32], b: &[f32]) -> f64 {
    let mut work = NerfWork::default();
    net.forward(params, points, dirs, &mut work);
    work.sigma
        .iter()
        .zip(a)
        .map(|(x, y)| (*x * *y) as f64)
        .sum::<f64>()
        + work
            .rgb
            .iter()
            .zip(b)
            .map(|(x, y)| (*x * *y) as f64)
            .sum::<f64>()
}

#[test]
fn gradient_matches_finite_differences() {
    let mut grid = spec(true);
    grid.position = Encoding::HashGrid(HashGridSpec {
        levels: 3,
        features: 2,
        log2_table: 6,
        min_res: 2,
        max_res: 9,
        min: [-1.0; 3],
        max: [1.0; 3],
    });
    for (vd, spec) in [(false, spec(false)), (true, spec(true)), (true, grid)] {
        let mut net = NerfNet::new(&spec);
        assert_eq!(net.multiply_adds(), spec.multiply_adds_per_sample());
        // Smooth in place of ReLU, so differences see no kinks (the
        // layers' own tests cover ReLU's slope); the wiring is the same.
        let smooth = Activation::Softplus { beta: 1.0 };
        for d in net
            .trunk
            .iter_mut()
            .chain([&mut net.density, &mut net.color_hidden])
        {
            d.act = smooth;
        }
        let params = net.init(1);
        let mut rng = SplitMix64::new(5);
        let rows = 40;
        let mut r = |n: usize, s: f32| {
            (0..n)
                .map(|_| s * (2.0 * rng.next_f32() - 1.0))
                .collect::<Vec<f32>>()
        };
        let points = r(rows * 3, 1.0);
        let dirs = r(rows * 3, 1.0);
        let a = r(rows, 1.0);
        let b = r(rows * 3, 1.0);
        let mut work = NerfWork::default();
        net.forward(&params, &points, &dirs, &mut work);
        let (mut ds, mut dc) = (a.clone(), b.clone());
        let mut grad = vec![0.0; net.len];
        net.backward(&params, &points, &mut work, &mut ds, &mut dc, &mut grad);
        // Every layer's first weights and its bias; the hash tables'
        // entries with the largest gradients and one without.
        let mut checks: Vec<(String, usize)> = Vec::new();
        if let PositionEncoding::Grid { grid, offset } = &net.position {
            let mut idx: Vec<usize> = (*offset..offset + grid.param_count()).collect();
            idx.sort_by(|&i, &j| grad[j].abs().total_cmp(&grad[i].abs()));
            assert!(grad[idx[0]] != 0.0 && grad[*idx.last().unwrap()] == 0.0);
            for &i in idx.iter().take(6).chain(idx.last()) {
                checks.push(("hashgrid".into(), i));
            }
        }
        for (name, d) in net.layers() {
            let bias = d.offset + d.fan_in() * d.out;
            for i in [
                d.offset,
                d.offset + 1,
                d.offset + d.fan_in() * d.out - 1,
                bias,
                d.end() - 1,
            ] {
                checks.push((name.clone(), i));
            }
        }
        {
            for (name, i) in checks {
                let h = 3e-3;
                let mut p = params.clone();
                p[i] += h;
                let up = probe(&net, &p, &points, &dirs, &a, &b);
                p[i] -= 2.0 * h;
                let down = probe(&net, &p, &points, &dirs, &a, &b);
                let fd = (up - down) / (2.0 * h as f64);
                let got = grad[i] as f64;
                assert!(
                    (got - fd).abs() < 2e-2 * (1.0 + fd.abs().max(got.abs())),
                    "view-dependent {vd}, {name} param {i}: {got} vs {fd}"
                );
            }
        }
    }
}

#[test]
fn density_ignores_the_view_direction() {
    let net = NerfNet::new(&spec(true));
    let params = net.init(2);
    let points = vec![0.1, 0.2, 0.3, -0.5, 0.4, 0.0];
    let mut w1 = NerfWork::default();
    let mut w2 = NerfWork::default();
    net.forward(&params, &points, &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0], &mut w1);
    net.forward(&params, &points, &[0.0, 0.0, 1.0, 0.6, 0.0, 0.8], &mut w2);
    assert_eq!(w1.sigma, w2.sigma);
    assert_ne!(w1.rgb, w2.rgb);
}

#[test]
fn only_view_dependent_fields_build_the_direction_branch() {
    let plain = NerfNet::new(&spec(false));
    assert!(plain.feature.is_none() && plain.direction.is_none());
    assert!(plain.layers().iter().all(|(n, _)| n != "feature"));
    let vd = NerfNet::new(&spec(true));
    assert!(vd.feature.is_some() && vd.len > plain.len);
}

#[test]
fn assignment_network_has_the_reference_size() {
    // 6 × 128 with the 39-wide embedding again at layer 3, view-dependent
    // with a 15-wide direction embedding and a 64-wide colour branch.
    let mut s = spec(true);
    s.position = Encoding::Harmonic(Spec {
        freqs: 6,
        include_input: true,
    });
    s.layers = 6;
    s.width = 128;
    s.skips = vec![3];
    s.color_width = 64;
    let net = NerfNet::new(&s);
    let want = (39 + 1) * 128
        + 4 * (128 + 1) * 128
        + (128 + 39 + 1) * 128
        + (128 + 1)
        + (128 + 1) * 128
        + (128 + 15 + 1) * 64
        + (64 + 1) * 3;
    assert_eq!(net.len, want);
}
