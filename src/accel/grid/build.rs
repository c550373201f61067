//! Per-frame grid build (CGT paper section 3; macrocells section 2.4).
//!
//! 1. Read the triangles: bounds of the traceable ones, counts of excluded ones.
//! 2. Resolution `N_a = d_a * cbrt(lambda N / V)` (section 3), rounded, at least 1.
//! 3. Count the references every triangle's (slightly widened) bounding box
//!    adds; fail with a capacity error before writing anything.
//! 4. Counting sort: per-cell counts, prefix sum, fill. No per-cell allocation:
//!    one `cell_start` array and one `refs` array, both preallocated.
//! 5. Macrocell flags: one bit per M x M x M block of cells.
//!
//! Every step but the resolution runs on the caller's workers
//! (`build_with`): the triangles split among them in order, cell counts and
//! the fill by atomic increments, then each cell's references sorted back
//! into triangle order, so the grid is the same for any number of workers.

use super::{Grid, GridInfo, GridParams};
use crate::error::{Error, Pool, Result};
use crate::geom::{Aabb, Excluded, Scene, TriVerts};
use crate::math;
use crate::mem::par::{MAX_WORKERS, Par, Parts, Serial, atomic_u32, share};
use core::sync::atomic::Ordering;
use glam::Vec3;

/// Widening of every triangle box at insertion, in cells (see `mod.rs`,
/// Deviations). Cell stepping errors are ~1e-6 cells; this is 1000x that.
pub const INSERT_EPS: f32 = 1e-3;

/// Longest axis is at least this many times any other (flat scenes, such as
/// a single ground quad, get a thin but non-zero slab).
const MIN_EXTENT_RATIO: f32 = 1e-3;

/// Largest resolution along one axis (keeps cell coordinates exact in f32).
const MAX_RES: u32 = 1 << 16;

#[inline]
fn tri_bounds(t: &TriVerts) -> Aabb {
    let mut b = Aabb::EMPTY;
    b.grow(Vec3::from(t.v0));
    b.grow(Vec3::from(t.v1));
    b.grow(Vec3::from(t.v2));
    b
}

/// Inclusive cell range covered by box `b` widened by `INSERT_EPS` cells.
#[inline]
fn cell_range(info: &GridInfo, b: &Aabb) -> ([u32; 3], [u32; 3]) {
    let lo = (b.min - info.bounds.min) * info.inv_cell - Vec3::splat(INSERT_EPS);
    let hi = (b.max - info.bounds.min) * info.inv_cell + Vec3::splat(INSERT_EPS);
    let mut a = [0u32; 3];
    let mut z = [0u32; 3];
    for k in 0..3 {
        let top = (info.res[k] - 1) as f32;
        a[k] = math::floor(lo[k]).clamp(0.0, top) as u32;
        z[k] = math::floor(hi[k]).clamp(0.0, top) as u32;
    }
    (a, z)
}

/// Resolution for `n` triangles in `bounds` at `lambda` (section 3):
/// `N_a = d_a * cbrt(lambda N / V)`. An axis that would get less than one
/// cell gets exactly one, and the others are solved again without it
/// (`k = (lambda N / prod d_a)^(1/m)` over the m remaining axes), so flat
/// scenes get about lambda x N cells instead of far more.
fn resolution(bounds: &Aabb, n: u32, lambda: f32) -> [u32; 3] {
    let d = bounds.diagonal();
    let target = lambda * n as f32;
    let mut free = [true; 3];
    let mut k = math::cbrt(target / (d.x * d.y * d.z));
    for _ in 0..3 {
        let m = free.iter().filter(|f| **f).count();
        let prod: f32 = (0..3).filter(|&a| free[a]).map(|a| d[a]).product();
        k = if m == 3 {
            math::cbrt(target / prod)
        } else {
            math::powf(target / prod, 1.0 / m as f32)
        };
        let mut changed = false;
        for a in 0..3 {
            if free[a] && d[a] * k < 1.0 && m > 1 {
                free[a] = false;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let mut r = [1u32; 3];
    for a in 0..3 {
        if free[a] {
            r[a] = (math::round(d[a] * k) as u32).clamp(1, MAX_RES);
        }
    }
    r
}

fn product(r: [u32; 3]) -> u64 {
    r[0] as u64 * r[1] as u64 * r[2] as u64
}

/// What one worker read of its share of the triangles.
#[derive(Clone, Copy)]
struct Read {
    bounds: Aabb,
    traceable: u32,
    non_finite: u32,
    zero_area: u32,
}

/// Calls `f(cell)` for every cell `(i, j, k)` of the box `a..=z`, `cell`
/// its index in x-fastest order (`rx`, `ry`: the resolution's first two).
#[inline(always)]
fn for_cells(a: [u32; 3], z: [u32; 3], rx: usize, ry: usize, mut f: impl FnMut(usize)) {
    for k in a[2]..=z[2] {
        for j in a[1]..=z[1] {
            let row = rx * (j as usize + ry * k as usize);
            for i in a[0]..=z[0] {
                f(row + i as usize);
            }
        }
    }
}

/// Rebuild `grid` from `scene` on the calling thread (`build_with` on
/// `Serial`). On error nothing in `grid` changes.
pub fn build(
    grid: &mut Grid<'_>,
    scene: &Scene<'_>,
    p: &GridParams,
    max_cells: u64,
    max_refs: u64,
) -> Result<GridInfo> {
    build_with(grid, scene, p, max_cells, max_refs, &Serial)
}

/// `build` on the caller's workers (`mem::par::Par`); the same grid for
/// any number of them. On error nothing in `grid` changes.
pub fn build_with(
    grid: &mut Grid<'_>,
    scene: &Scene<'_>,
    p: &GridParams,
    max_cells: u64,
    max_refs: u64,
    par: &dyn Par,
) -> Result<GridInfo> {
    let workers = crate::mem::par::workers_of(par)?;
    if !(p.lambda.is_finite() && p.lambda > 0.0 && p.lambda <= 1024.0) {
        return Err(Error::InvalidArgument("lambda must be in (0, 1024]"));
    }
    if p.macrocell > 64 {
        return Err(Error::InvalidArgument("macrocell side must be <= 64"));
    }
    let n_in = scene.triangle_count();
    if n_in as usize > grid.pools_mut().tris.len() {
        return Err(Error::Capacity {
            pool: Pool::Triangles,
            needed: n_in as u64,
            available: grid.pools_mut().tris.len() as u64,
        });
    }

    // 1. Bounds and exclusions (read only), each worker a share in order.
    let nw = n_in as usize;
    let mut reads = [Read {
        bounds: Aabb::EMPTY,
        traceable: 0,
        non_finite: 0,
        zero_area: 0,
    }; MAX_WORKERS];
    {
        let rs = Parts::even(&mut reads[..workers], workers);
        par.run(&|w| {
            let r = &mut rs.get(w)[0];
            for t in share(nw, w, workers) {
                let tri = scene.triangle(t as u32);
                match Scene::classify(&tri) {
                    None => {
                        r.traceable += 1;
                        r.bounds = r.bounds.union(&tri_bounds(&tri));
                    }
                    Some(Excluded::NonFinite) => r.non_finite += 1,
                    Some(Excluded::ZeroArea) => r.zero_area += 1,
                }
            }
        });
    }
    let reads = &reads[..workers];
    let mut bounds = reads.iter().fold(Aabb::EMPTY, |b, r| b.union(&r.bounds));
    let n: u32 = reads.iter().map(|r| r.traceable).sum();
    let bad_nf: u32 = reads.iter().map(|r| r.non_finite).sum();
    let bad_za: u32 = reads.iter().map(|r| r.zero_area).sum();

    // 2. Resolution.
    let mut info = GridInfo {
        triangles_in: n_in,
        triangles: n,
        excluded_non_finite: bad_nf,
        excluded_zero_area: bad_za,
        test: p.test,
        ..GridInfo::default()
    };
    info.scene_bounds = bounds;
    if n == 0 {
        bounds = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        info.res = [1, 1, 1];
    } else {
        let d = bounds.diagonal();
        let min_ext = d.max_element() * MIN_EXTENT_RATIO;
        for a in 0..3 {
            if d[a] < min_ext {
                let pad = 0.5 * (min_ext - d[a]);
                bounds.min[a] -= pad;
                bounds.max[a] += pad;
            }
        }
        let mut lambda = p.lambda;
        info.res = resolution(&bounds, n, lambda);
        if product(info.res) > max_cells {
            if !p.fit {
                return Err(Error::Capacity {
                    pool: Pool::GridCells,
                    needed: product(info.res),
                    available: max_cells,
                });
            }
            // Fit mode: lower lambda until the cells fit (rounding may need a few steps).
            while product(info.res) > max_cells {
                lambda *= 0.98 * (max_cells as f32 / product(info.res) as f32);
                info.res = resolution(&bounds, n, lambda);
                if info.res == [1, 1, 1] {
                    break;
                }
            }
            if product(info.res) > max_cells {
                return Err(Error::Capacity {
                    pool: Pool::GridCells,
                    needed: product(info.res),
                    available: max_cells,
                });
            }
        }
    }
    let cells = product(info.res);
    info.lambda = if n > 0 { cells as f32 / n as f32 } else { 0.0 };
    info.bounds = bounds;
    let res_f = Vec3::new(info.res[0] as f32, info.res[1] as f32, info.res[2] as f32);
    info.cell_size = bounds.diagonal() / res_f;
    info.inv_cell = res_f / bounds.diagonal();
    info.macrocell = p.macrocell.max(1);
    for a in 0..3 {
        info.macro_res[a] = info.res[a].div_ceil(info.macrocell);
    }

    // 3. Count references (read only) and check capacity.
    let mut counts = [0u64; MAX_WORKERS];
    if n > 0 {
        let cs = Parts::even(&mut counts[..workers], workers);
        let info = &info;
        par.run(&|w| {
            let mut refs = 0u64;
            for t in share(nw, w, workers) {
                let tri = scene.triangle(t as u32);
                if Scene::classify(&tri).is_none() {
                    let (a, z) = cell_range(info, &tri_bounds(&tri));
                    refs += (z[0] - a[0] + 1) as u64
                        * (z[1] - a[1] + 1) as u64
                        * (z[2] - a[2] + 1) as u64;
                }
            }
            cs.get(w)[0] = refs;
        });
    }
    let refs: u64 = counts[..workers].iter().sum();
    let pools = grid.pools_mut();
    if p.test == crate::geom::TriTest::Projection && pools.proj.len() < n_in as usize {
        return Err(Error::InvalidArgument(
            "the projection test needs Limits::projection_test",
        ));
    }
    if refs > max_refs.min(pools.refs.len() as u64) {
        return Err(Error::Capacity {
            pool: Pool::GridRefs,
            needed: refs,
            available: max_refs.min(pools.refs.len() as u64),
        });
    }
    if cells + 1 > pools.cell_start.len() as u64 {
        return Err(Error::Capacity {
            pool: Pool::GridCells,
            needed: cells,
            available: pools.cell_start.len() as u64 - 1,
        });
    }
    info.refs = refs as u32;

    // 4. Commit: store triangles, count per cell, prefix sum, fill.
    let cells = cells as usize;
    let (rx, ry) = (info.res[0] as usize, info.res[1] as usize);
    crate::fault_point!(GridBuild);
    let cell_start = &mut pools.cell_start[..cells + 1];
    cell_start.fill(0);
    // Worker w stores its traceable triangles from `at[w]` on, in order.
    let mut at = [0usize; MAX_WORKERS + 1];
    for w in 0..workers {
        at[w + 1] = at[w] + reads[w].traceable as usize;
    }
    let c = n as usize;
    let proj_on = p.test == crate::geom::TriTest::Projection;
    {
        let ts = Parts::at(&mut pools.tris[..c], &at[..=workers]);
        let ps = Parts::at(
            if proj_on {
                &mut pools.proj[..c]
            } else {
                &mut []
            },
            if proj_on { &at[..=workers] } else { &[] },
        );
        let ids = Parts::at(&mut pools.tri_ids[..c], &at[..=workers]);
        let counts = atomic_u32(cell_start);
        let info = &info;
        par.run(&|w| {
            let (ts, ids) = (ts.get(w), ids.get(w));
            let ps = if proj_on { ps.get(w) } else { &mut [] };
            let mut k = 0;
            for t in share(nw, w, workers) {
                let tri = scene.triangle(t as u32);
                if Scene::classify(&tri).is_some() {
                    continue;
                }
                ts[k] = tri;
                if proj_on {
                    // Wald 2004 data, rebuilt with the grid (CGT paper section 3).
                    ps[k] = crate::geom::ProjTri::new(&tri);
                }
                ids[k] = t as u32;
                k += 1;
                let (a, z) = cell_range(info, &tri_bounds(&tri));
                for_cells(a, z, rx, ry, |cell| {
                    counts[cell + 1].fetch_add(1, Ordering::Relaxed);
                });
            }
        });
    }
    // Prefix sum: each worker's share of the cells summed, then scanned
    // from the shares before it.
    let mut part_sums = [0u32; MAX_WORKERS + 1];
    {
        let (counts, sums) = (
            &cell_start[1..],
            Parts::even(&mut part_sums[..workers], workers),
        );
        par.run(&|w| {
            let r = share(cells, w, workers);
            sums.get(w)[0] = counts[r].iter().sum();
        });
    }
    let mut carry = 0u32;
    for s in &mut part_sums[..workers] {
        (*s, carry) = (carry, carry + *s);
    }
    {
        let cs = Parts::even(&mut cell_start[1..], workers);
        par.run(&|w| {
            let mut acc = part_sums[w];
            for x in cs.get(w) {
                acc += *x;
                *x = acc;
            }
        });
    }
    // Fill: cell_start[c] is the write cursor of cell c; afterwards it holds
    // the end of cell c, and one shift restores the starts. Workers fill
    // at once (cursors taken atomically), so a cell's references come in
    // any order: each cell is then sorted back into triangle order.
    {
        let (cursor, out) = (
            atomic_u32(cell_start),
            atomic_u32(&mut pools.refs[..refs as usize]),
        );
        let (tris, info) = (&pools.tris[..c], &info);
        par.run(&|w| {
            for ci in share(c, w, workers) {
                let (a, z) = cell_range(info, &tri_bounds(&tris[ci]));
                for_cells(a, z, rx, ry, |cell| {
                    let at = cursor[cell].fetch_add(1, Ordering::Relaxed);
                    out[at as usize].store(ci as u32, Ordering::Relaxed);
                });
            }
        });
    }
    cell_start.copy_within(0..cells, 1);
    cell_start[0] = 0;
    if workers > 1 {
        // Cut the references at cell boundaries near the even shares.
        let mut cut = [0usize; MAX_WORKERS + 1];
        let mut cell_cut = [0usize; MAX_WORKERS + 1];
        for w in 1..workers {
            cell_cut[w] = share(cells, w, workers).start;
            cut[w] = cell_start[cell_cut[w]] as usize;
        }
        (cell_cut[workers], cut[workers]) = (cells, refs as usize);
        let rs = Parts::at(&mut pools.refs[..refs as usize], &cut[..=workers]);
        let starts = &*cell_start;
        par.run(&|w| {
            let part = rs.get(w);
            let base = cut[w];
            for cell in cell_cut[w]..cell_cut[w + 1] {
                let (a, b) = (
                    starts[cell] as usize - base,
                    starts[cell + 1] as usize - base,
                );
                part[a..b].sort_unstable();
            }
        });
    }

    // 5. Macrocell occupancy, each worker a share of the z slices (a word
    // may hold bits of two shares: set atomically).
    let m = info.macrocell as usize;
    let mr = info.macro_res;
    let words = (product(mr) as usize).div_ceil(32);
    let bits = &mut pools.macro_bits[..words];
    bits.fill(0);
    let rz = info.res[2] as usize;
    {
        let (bits, starts) = (atomic_u32(bits), &*cell_start);
        par.run(&|w| {
            for k in share(rz, w, workers) {
                for j in 0..ry {
                    let row = rx * (j + ry * k);
                    let mrow = mr[0] as usize * (j / m + mr[1] as usize * (k / m));
                    for i in 0..rx {
                        if starts[row + i + 1] != starts[row + i] {
                            let mi = mrow + i / m;
                            bits[mi >> 5].fetch_or(1 << (mi & 31), Ordering::Relaxed);
                        }
                    }
                }
            }
        });
    }

    grid.set_info(info);
    Ok(info)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accel::grid::GridPools;
    use crate::accel::testkit::Backwards;
    use crate::geom::{ProjTri, TriTest};

    /// Pools for a grid of `n` triangles (16 cells and 64 references per
    /// triangle).
    struct Store {
        tris: Vec<TriVerts>,
        proj: Vec<ProjTri>,
        ids: Vec<u32>,
        starts: Vec<u32>,
        rs: Vec<u32>,
        bits: Vec<u32>,
        cells: usize,
        refs: usize,
    }

    impl Store {
        fn new(n: usize) -> Store {
            let (cells, refs) = (16 * n + 64, 64 * n + 64);
            Store {
                tris: vec![TriVerts::default(); n],
                proj: vec![ProjTri::default(); n],
                ids: vec![0; n],
                starts: vec![0; cells + 1],
                rs: vec![0; refs],
                bits: vec![0; cells / 32 + 1],
                cells,
                refs,
            }
        }
        fn grid(&mut self) -> Grid<'_> {
            Grid::new(GridPools {
                tris: &mut self.tris,
                proj: &mut self.proj,
                tri_ids: &mut self.ids,
                cell_start: &mut self.starts,
                refs: &mut self.rs,
                macro_bits: &mut self.bits,
            })
        }
    }

    /// Everything a build wrote, as bits.
    type Built = (
        GridInfo,
        Vec<u32>,
        Vec<u32>,
        Vec<u32>,
        Vec<u32>,
        Vec<u32>,
        Vec<u32>,
    );

    fn built(vertices: &[f32], indices: &[u32], p: &GridParams, par: &dyn Par) -> Built {
        let scene = Scene::from_f32(vertices, indices).unwrap();
        let n = scene.triangle_count() as usize;
        let mut st = Store::new(n);
        let (cells, refs) = (st.cells, st.refs);
        let mut grid = st.grid();
        let info = build_with(&mut grid, &scene, p, cells as u64, refs as u64, par).unwrap();
        let v = grid.view().unwrap();
        let words = |x: &[f32]| x.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        let tris: Vec<f32> = v
            .tris
            .iter()
            .flat_map(|t| t.v0.into_iter().chain(t.v1).chain(t.v2))
            .collect();
        let proj: Vec<u32> = bytemuck::cast_slice(v.proj).to_vec();
        (
            info,
            words(&tris),
            proj,
            v.tri_ids.to_vec(),
            v.cell_start.to_vec(),
            v.refs.to_vec(),
            v.macro_bits.to_vec(),
        )
    }

    /// A build split among workers writes the calling thread's grid, bit
    /// for bit: triangles, ids, cells, references in triangle order and
    /// macrocell bits, with and without the projection data.
    #[test]
    fn workers_build_the_calling_threads_grid() {
        for name in ["gears", "balls", "animated"] {
            let s = crate::scenes::builtin(name).unwrap();
            for test in [TriTest::MollerTrumbore, TriTest::Projection] {
                let p = GridParams {
                    test,
                    ..GridParams::default()
                };
                let one = built(&s.mesh.vertices, &s.mesh.indices, &p, &Serial);
                assert!(
                    one.0.refs as usize > one.3.len(),
                    "{name}: triangles span cells"
                );
                for workers in [2, 3, 7] {
                    let got = built(&s.mesh.vertices, &s.mesh.indices, &p, &Backwards(workers));
                    assert!(
                        got == one,
                        "{name} {test:?}: {workers} workers built another grid"
                    );
                }
            }
        }
    }

    /// A joined build that fails its capacity check leaves the last grid
    /// as it was, and an empty scene builds on any number of workers.
    #[test]
    fn workers_keep_the_grid_on_error_and_build_empty_scenes() {
        let s = crate::scenes::builtin("gears").unwrap();
        let scene = Scene::from_f32(&s.mesh.vertices, &s.mesh.indices).unwrap();
        let n = scene.triangle_count() as usize;
        let mut st = Store::new(n);
        let (cells, refs) = (st.cells, st.refs);
        let mut grid = st.grid();
        let p = GridParams::default();
        let (c, r) = (cells as u64, refs as u64);
        let info = build_with(&mut grid, &scene, &p, c, r, &Backwards(2)).unwrap();
        let snapshot = |g: &Grid<'_>| {
            let v = g.view().unwrap();
            (
                *v.info,
                v.cell_start.to_vec(),
                v.refs.to_vec(),
                v.tri_ids.to_vec(),
            )
        };
        let before = snapshot(&grid);
        let e = build_with(
            &mut grid,
            &scene,
            &p,
            c,
            info.refs as u64 - 1,
            &Backwards(3),
        );
        assert!(
            matches!(
                e,
                Err(Error::Capacity {
                    pool: Pool::GridRefs,
                    ..
                })
            ),
            "{e:?}"
        );
        assert!(
            snapshot(&grid) == before,
            "a refused build changed the grid"
        );
        let empty = build_with(&mut grid, &Scene::empty(), &p, c, r, &Backwards(3)).unwrap();
        assert_eq!((empty.triangles, empty.refs), (0, 0));
        assert!(build_with(&mut grid, &scene, &p, c, r, &Backwards(MAX_WORKERS + 1)).is_err());
    }
}
