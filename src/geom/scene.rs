//! Scene input: the caller's vertex and index buffers, borrowed (zero copy).
//!
//! Vertices are three `f32` (x, y, z) at a caller-given byte stride, so an
//! engine can hand over its interleaved vertex buffer as it is. Indices are
//! `u32` triples. `Scene::new` checks every index once; triangles with
//! non-finite vertices or zero area are not errors: structures skip them at
//! build and count them in their stats.

use crate::error::{Error, Result};
use crate::geom::triangle::TriVerts;

/// Borrowed triangle geometry. Cheap to copy.
#[derive(Clone, Copy, Debug)]
pub struct Scene<'g> {
    vertices: &'g [u8],
    stride: usize,
    vertex_count: u32,
    indices: &'g [u32],
}

/// Why a triangle is left out of a structure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Excluded {
    /// A vertex has a NaN or infinite coordinate.
    NonFinite,
    /// The cross product of two edges is exactly zero (points or lines).
    ZeroArea,
}

/// How many triangles ahead `Scene::prefetch_ahead` requests vertices.
const GATHER_AHEAD: usize = 32;

impl<'g> Scene<'g> {
    /// Borrow `vertex_count` vertices of three `f32` each, `stride` bytes
    /// apart, from `vertices`, and `indices.len() / 3` triangles.
    ///
    /// Errors: stride below 12 or not a multiple of 4, a vertex buffer shorter
    /// than `vertex_count` vertices, an index count that is not a multiple of
    /// 3, a count above `u32::MAX`, or an index `>= vertex_count`.
    pub fn new(
        vertices: &'g [u8],
        stride: usize,
        vertex_count: u32,
        indices: &'g [u32],
    ) -> Result<Self> {
        if stride < 12 || !stride.is_multiple_of(4) {
            return Err(Error::InvalidArgument(
                "vertex stride must be >= 12 and a multiple of 4",
            ));
        }
        if vertex_count > 0 {
            let need = (vertex_count as usize - 1)
                .checked_mul(stride)
                .and_then(|x| x.checked_add(12))
                .ok_or(Error::InvalidArgument("vertex buffer size overflows"))?;
            if vertices.len() < need {
                return Err(Error::InvalidArgument(
                    "vertex buffer shorter than vertex_count * stride",
                ));
            }
        }
        if !indices.len().is_multiple_of(3) {
            return Err(Error::InvalidArgument(
                "index count must be a multiple of 3",
            ));
        }
        if indices.len() / 3 > u32::MAX as usize {
            return Err(Error::InvalidArgument("too many triangles"));
        }
        if let Some(pos) = indices.iter().position(|&i| i >= vertex_count) {
            return Err(Error::IndexOutOfRange {
                triangle: (pos / 3) as u32,
                index: indices[pos],
                vertex_count,
            });
        }
        Ok(Scene {
            vertices,
            stride,
            vertex_count,
            indices,
        })
    }

    /// Packed xyz vertices (stride 12) and indices the caller made valid
    /// (every one below `vertex_count`, a multiple of 3 of them): no scan.
    /// Crate-internal meshes only (the flattened two-level scene).
    pub(crate) fn trusted(vertices: &'g [u8], vertex_count: u32, indices: &'g [u32]) -> Self {
        debug_assert!(vertices.len() >= 12 * vertex_count as usize);
        debug_assert!(indices.len().is_multiple_of(3) && indices.iter().all(|&i| i < vertex_count));
        Scene {
            vertices,
            stride: 12,
            vertex_count,
            indices,
        }
    }

    /// Packed xyz vertices (stride 12).
    pub fn from_f32(vertices: &'g [f32], indices: &'g [u32]) -> Result<Self> {
        let count = u32::try_from(vertices.len() / 3)
            .map_err(|_| Error::InvalidArgument("too many vertices"))?;
        Scene::new(bytemuck::cast_slice(vertices), 12, count, indices)
    }

    /// An empty scene.
    pub const fn empty() -> Scene<'static> {
        Scene {
            vertices: &[],
            stride: 12,
            vertex_count: 0,
            indices: &[],
        }
    }

    #[inline]
    pub fn triangle_count(&self) -> u32 {
        (self.indices.len() / 3) as u32
    }
    #[inline]
    pub fn vertex_count(&self) -> u32 {
        self.vertex_count
    }

    /// Vertex `i` (must be `< vertex_count`).
    #[inline]
    pub fn vertex(&self, i: u32) -> [f32; 3] {
        let at = i as usize * self.stride;
        bytemuck::pod_read_unaligned(&self.vertices[at..at + 12])
    }

    /// The vertices of triangle `t` (must be `< triangle_count`).
    #[inline(always)]
    pub fn triangle(&self, t: u32) -> TriVerts {
        let k = t as usize * 3;
        TriVerts {
            v0: self.vertex(self.indices[k]),
            v1: self.vertex(self.indices[k + 1]),
            v2: self.vertex(self.indices[k + 2]),
        }
    }

    /// A hint for walks that read triangles in an order of their own (the
    /// refit's leaf order, the fast build's Morton order), at slot `k` of
    /// `ids`: triangle `ids[k + GATHER_AHEAD]`'s vertices are requested,
    /// and the index entries of the one `GATHER_AHEAD` further, so both
    /// dependent loads of each gather have arrived when it is read. These
    /// gathers miss the cache in large meshes; measured (crytek sponza and
    /// conference, refit on 1 thread, interleaved): 14.6 -> 10.7 ms and
    /// 17.7 -> 13.7 ms at a distance of 16, 3 % less again at 32.
    #[inline(always)]
    pub(crate) fn prefetch_ahead(&self, ids: &[u32], k: usize) {
        use crate::mem::prefetch::prefetch;
        if let Some(&t) = ids.get(k + 2 * GATHER_AHEAD) {
            prefetch(&self.indices[t as usize * 3]);
        }
        if let Some(&t) = ids.get(k + GATHER_AHEAD) {
            let at = t as usize * 3;
            for &i in &self.indices[at..at + 3] {
                prefetch(&self.vertices[i as usize * self.stride]);
            }
        }
    }

    /// `None` when triangle `t` can be traced, else why it is excluded.
    #[inline]
    pub fn classify(tri: &TriVerts) -> Option<Excluded> {
        let all = tri.v0.iter().chain(tri.v1.iter()).chain(tri.v2.iter());
        if !all.clone().all(|x| x.is_finite()) {
            return Some(Excluded::NonFinite);
        }
        let n = tri.normal();
        if n.x == 0.0 && n.y == 0.0 && n.z == 0.0 {
            return Some(Excluded::ZeroArea);
        }
        None
    }
}
