//! Scene sources: Wavefront OBJ files (tobj, every model merged into one
//! vertex and one index buffer) and the built-in scenes (`builtin:NAME`).

use crate::{Failure, OrFail};
use glam::Vec3;
use sheaf::scenes::{self, View};
use std::path::Path;

/// A scene in the layout `sheaf::Scene::from_f32` borrows.
pub struct Loaded {
    /// What the user named: the path, or `builtin:NAME`.
    pub label: String,
    pub vertices: Vec<f32>,
    pub indices: Vec<u32>,
    /// Views and light of a built-in scene (None for OBJ files).
    pub builtin: Option<(Vec<View>, Vec3)>,
    /// Triangles the file's faces describe that the loader did not return.
    pub skipped: u64,
}

impl Loaded {
    pub fn vertex_count(&self) -> u32 {
        (self.vertices.len() / 3) as u32
    }
    pub fn scene(&self) -> Result<sheaf::Scene<'_>, Failure> {
        sheaf::Scene::from_f32(&self.vertices, &self.indices).or_fail(|| format!("scene {}", self.label))
    }
    /// Bounds of the vertices the triangles use (finite ones only), or None.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for &i in &self.indices {
            let k = 3 * i as usize;
            let p = Vec3::from_slice(&self.vertices[k..k + 3]);
            if p.is_finite() {
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        (lo.x <= hi.x).then_some((lo, hi))
    }
}

/// Load `spec`: `builtin:NAME` or the path of an OBJ file.
pub fn load(spec: &str) -> Result<Loaded, Failure> {
    if let Some(name) = spec.strip_prefix("builtin:") {
        let s = scenes::builtin(name).ok_or_else(|| {
            Failure(format!("unknown built-in scene '{name}' (known: {})", scenes::BUILTIN_NAMES.join(", ")))
        })?;
        return Ok(Loaded {
            label: spec.to_string(),
            vertices: s.mesh.vertices,
            indices: s.mesh.indices,
            builtin: Some((s.views, s.light)),
            skipped: 0,
        });
    }
    load_obj(Path::new(spec))
}

/// Triangles the `f` lines of an OBJ text describe (sum of arity - 2).
fn face_triangles(text: &[u8]) -> u64 {
    text.split(|&b| b == b'\n')
        .filter(|l| l.len() > 1 && l[0] == b'f' && l[1].is_ascii_whitespace())
        .map(|l| l[1..].split(|b| b.is_ascii_whitespace()).filter(|t| !t.is_empty()).count().saturating_sub(2) as u64)
        .sum()
}

fn load_obj(path: &Path) -> Result<Loaded, Failure> {
    let text = std::fs::read(path).or_fail(|| format!("cannot read {}", path.display()))?;
    // tobj's `merging` and `reordering` features add fields: keep the update.
    #[allow(clippy::needless_update)]
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Materials are not used: never open the .mtl.
    let (models, _) = tobj::load_obj_buf(&mut &text[..], &opts, |_| Err(tobj::LoadError::OpenFileFailed))
        .or_fail(|| format!("cannot parse {} as OBJ", path.display()))?;
    let (nv, ni) =
        models.iter().fold((0usize, 0usize), |(v, i), m| (v + m.mesh.positions.len(), i + m.mesh.indices.len()));
    if nv / 3 > u32::MAX as usize || ni / 3 > u32::MAX as usize {
        return Err(Failure(format!("{}: more than 2^32 vertices or triangles", path.display())));
    }
    let (mut vertices, mut indices) = (Vec::with_capacity(nv), Vec::with_capacity(ni));
    for m in &models {
        let base = (vertices.len() / 3) as u32;
        vertices.extend_from_slice(&m.mesh.positions);
        indices.extend(m.mesh.indices.iter().map(|&i| i + base));
    }
    let skipped = face_triangles(&text).saturating_sub(indices.len() as u64 / 3);
    Ok(Loaded { label: path.display().to_string(), vertices, indices, builtin: None, skipped })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_faces() {
        assert_eq!(face_triangles(b"v 0 0 0\nf 1 2 3\nf 1/1/1 2/2/2 3/3/3 4/4/4\nfoo\nf\n"), 3);
    }

    #[test]
    fn loads_a_small_obj_and_rejects_bad_ones() {
        let dir = std::env::temp_dir().join(format!("sheaf-cli-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("quad.obj");
        std::fs::write(
            &good,
            "o a\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf 5 6 7\n",
        )
        .unwrap();
        let l = load(good.to_str().unwrap()).unwrap();
        assert_eq!((l.indices.len() / 3, l.vertex_count(), l.skipped), (3, 7, 0));
        assert!(l.indices.iter().all(|&i| i < 7));
        let bad = dir.join("bad.obj");
        std::fs::write(&bad, "v 0 0 0\nf 1 2 9\n").unwrap();
        assert!(load(bad.to_str().unwrap()).is_err());
        assert!(load(dir.join("missing.obj").to_str().unwrap()).is_err());
        assert!(load("builtin:nope").is_err());
        assert!(load("builtin:tetra").unwrap().builtin.is_some());
        std::fs::remove_dir_all(&dir).ok();
    }
}
