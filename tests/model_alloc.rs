//! `eval` is called ~10^7 times per table: it must not allocate, for any model (sums
//! included, with any channel count).

use brdfpack::brdf::Brdf;
use brdfpack::geometry::Vec3;
use brdfpack::model::Model;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Counts allocations made by the current test binary.
struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn eval_does_not_allocate() {
    let specs = [
        "lambert:albedo=0.8/0.5/0.2",
        "phong:exponent=1e4",
        "blinn-phong",
        "torrance-sparrow:fresnel=au",
        "ggx:alpha_x=0.1,alpha_y=0.3,fresnel=schlick,f0=0.04",
        "beckmann:g1=exact,fresnel=dielectric,ior=1.5",
        "ward:variant=ward",
        "oren-nayar",
        "ashikhmin-shirley:nu=10,nv=1000",
        "lafortune:norm=ngan,lobe=-1:-1:1:20,lobe=0.5:0.5:0.2:3",
        "lambert:albedo=0.1 + ggx:fresnel=au + ward",
    ];
    // A 40-channel sum exercises the chunked stack buffer (chunks of 32).
    let spectral: Vec<String> = (0..40).map(|i| format!("{}", 0.01 * i as f64)).collect();
    let wide = format!(
        "lambert:albedo={} + ggx:scale={}",
        spectral.join("/"),
        spectral.join("/")
    );
    let mut models: Vec<Model> = specs.iter().map(|s| Model::parse(s).unwrap()).collect();
    models.push(Model::parse(&wide).unwrap());
    let mut out = vec![0.0; 64];
    let wi = Vec3::new(0.36, 0.48, 0.8);
    let wo = Vec3::new(-0.48, -0.6, 0.64);
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    for m in &models {
        let c = m.channels().len();
        for _ in 0..100 {
            m.eval(wi, wo, &mut out[..c]);
        }
    }
    let after = ALLOCATIONS.load(Ordering::Relaxed);
    assert_eq!(after - before, 0, "eval allocated {} times", after - before);
    // The wide sum is the per-channel sum of its terms.
    let mut parts = [vec![0.0; 40], vec![0.0; 40]];
    let wide_model = models.last().unwrap();
    let brdfpack::model::Model::Sum(s) = wide_model else {
        panic!("not a sum")
    };
    s.terms[0].eval(wi, wo, &mut parts[0]);
    s.terms[1].eval(wi, wo, &mut parts[1]);
    wide_model.eval(wi, wo, &mut out[..40]);
    for ch in 0..40 {
        assert_eq!(out[ch], parts[0][ch] + parts[1][ch], "channel {ch}");
    }
}
