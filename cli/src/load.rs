//! Scene sources: Wavefront OBJ files (tobj, every model merged into one
//! vertex and one index buffer, materials from the .mtl files the OBJ
//! names) and the built-in scenes (`builtin:NAME`).

use anyhow::{Context as _, Result, anyhow, bail};
use glam::Vec3;
use sheaf::render::material::{DEFAULT_MATERIAL, Material, MaterialRange, Materials};
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
    /// Materials of the OBJ's .mtl files (see `material`); empty for
    /// built-in scenes and when no .mtl could be read.
    pub materials: Vec<Material>,
    /// Which triangles use which of `materials`, sorted by first triangle
    /// (`DEFAULT_MATERIAL`: faces without a known material).
    pub ranges: Vec<MaterialRange>,
}

impl Loaded {
    pub fn vertex_count(&self) -> u32 {
        (self.vertices.len() / 3) as u32
    }
    pub fn scene(&self) -> Result<sheaf::Scene<'_>> {
        sheaf::Scene::from_f32(&self.vertices, &self.indices)
            .with_context(|| format!("scene {}", self.label))
    }
    /// The materials as the Whitted renderer borrows them.
    #[allow(dead_code)] // for commands rendering OBJ materials
    pub fn materials(&self) -> Materials<'_> {
        Materials {
            materials: &self.materials,
            ranges: &self.ranges,
        }
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

/// Load `spec`: `builtin:NAME`, `stress:NAME` (the adversarial scenes of
/// `sheaf_stress`) or the path of an OBJ file.
pub fn load(spec: &str) -> Result<Loaded> {
    if let Some(name) = spec.strip_prefix("stress:") {
        let s = sheaf_stress::stress_scene(name).ok_or_else(|| {
            anyhow!(
                "unknown stress scene '{name}' (known: {})",
                sheaf_stress::STRESS_SCENE_NAMES.join(", ")
            )
        })?;
        return Ok(Loaded::from_builtin(spec, s));
    }
    if let Some(name) = spec.strip_prefix("builtin:") {
        let s = scenes::builtin(name).ok_or_else(|| {
            anyhow!(
                "unknown built-in scene '{name}' (known: {})",
                scenes::BUILTIN_NAMES.join(", ")
            )
        })?;
        return Ok(Loaded::from_builtin(spec, s));
    }
    load_obj(Path::new(spec))
}

impl Loaded {
    /// A generated scene (built-in or stress) with its views and light.
    pub fn from_builtin(label: &str, s: scenes::BuiltinScene) -> Loaded {
        Loaded {
            label: label.to_string(),
            vertices: s.mesh.vertices,
            indices: s.mesh.indices,
            builtin: Some((s.views, s.light)),
            skipped: 0,
            materials: Vec::new(),
            ranges: Vec::new(),
        }
    }
}

/// Triangles the `f` lines of an OBJ text describe (sum of arity - 2).
fn face_triangles(text: &[u8]) -> u64 {
    text.split(|&b| b == b'\n')
        .filter(|l| l.len() > 1 && l[0] == b'f' && l[1].is_ascii_whitespace())
        .map(|l| {
            l[1..]
                .split(|b| b.is_ascii_whitespace())
                .filter(|t| !t.is_empty())
                .count()
                .saturating_sub(2) as u64
        })
        .sum()
}

fn load_obj(path: &Path) -> Result<Loaded> {
    let text = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    // tobj's `merging` and `reordering` features add fields: keep the update.
    #[allow(clippy::needless_update)]
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // .mtl files are named relative to the OBJ's folder.
    let dir = path.parent().unwrap_or(Path::new(""));
    let (models, mtl) = tobj::load_obj_buf(&mut &text[..], &opts, |m| tobj::load_mtl(dir.join(m)))
        .with_context(|| format!("cannot parse {} as OBJ", path.display()))?;
    let mtl = mtl.unwrap_or_else(|e| {
        eprintln!("warning: {}: cannot load its materials ({e}): every surface diffuse with the default albedo", path.display());
        Vec::new()
    });
    let (nv, ni) = models.iter().fold((0usize, 0usize), |(v, i), m| {
        (v + m.mesh.positions.len(), i + m.mesh.indices.len())
    });
    if nv / 3 > u32::MAX as usize || ni / 3 > u32::MAX as usize {
        bail!("{}: more than 2^32 vertices or triangles", path.display());
    }
    let (mut vertices, mut indices) = (Vec::with_capacity(nv), Vec::with_capacity(ni));
    let mut ranges: Vec<MaterialRange> = Vec::new();
    for m in &models {
        let base = (vertices.len() / 3) as u32;
        let first = (indices.len() / 3) as u32;
        vertices.extend_from_slice(&m.mesh.positions);
        indices.extend(m.mesh.indices.iter().map(|&i| i + base));
        let material = match m.mesh.material_id {
            Some(k) if k < mtl.len() => k as u32,
            _ => DEFAULT_MATERIAL,
        };
        let current = ranges.last().map_or(DEFAULT_MATERIAL, |r| r.material);
        if indices.len() / 3 > first as usize && material != current {
            ranges.push(MaterialRange { first, material });
        }
    }
    let materials = mtl.iter().map(material).collect();
    let skipped = face_triangles(&text).saturating_sub(indices.len() as u64 / 3);
    Ok(Loaded {
        label: path.display().to_string(),
        vertices,
        indices,
        builtin: None,
        skipped,
        materials,
        ranges,
    })
}

/// One .mtl material: `Kd` the diffuse colour (default: the renderer's
/// default albedo); reflectance the largest `Ks` component for illumination
/// models 3, 5 and 7 (ray-traced reflection), else 0; transmittance `Tr`,
/// else `1 - d` when `d < 1`, else 0; `Ni` the index of refraction (default
/// 1.5 for transmissive materials, else 1). Values are clamped into range,
/// reflectance so that reflectance + transmittance <= 1.
fn material(m: &tobj::Material) -> Material {
    let unit = |x: f32| {
        if x.is_finite() {
            x.clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let diffuse = m
        .diffuse
        .map_or(sheaf::Shading::default().albedo, |d| d.map(unit));
    let reflect = match (m.illumination_model, m.specular) {
        (Some(3 | 5 | 7), Some(ks)) => unit(ks[0].max(ks[1]).max(ks[2])),
        _ => 0.0,
    };
    let tr = m
        .unknown_param
        .get("Tr")
        .and_then(|t| t.trim().parse::<f32>().ok());
    let transmit = match (tr, m.dissolve) {
        (Some(t), _) => unit(t),
        (None, Some(d)) if d < 1.0 => unit(1.0 - d),
        _ => 0.0,
    };
    let ior = match m.optical_density {
        Some(n) if n.is_finite() && n > 0.0 => n,
        _ if transmit > 0.0 => 1.5,
        _ => 1.0,
    };
    Material {
        diffuse,
        reflect: reflect.min(1.0 - transmit),
        transmit,
        ior,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_faces() {
        assert_eq!(
            face_triangles(b"v 0 0 0\nf 1 2 3\nf 1/1/1 2/2/2 3/3/3 4/4/4\nfoo\nf\n"),
            3
        );
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
        assert_eq!(
            (l.indices.len() / 3, l.vertex_count(), l.skipped),
            (3, 7, 0)
        );
        assert!(l.indices.iter().all(|&i| i < 7));
        let bad = dir.join("bad.obj");
        std::fs::write(&bad, "v 0 0 0\nf 1 2 9\n").unwrap();
        assert!(load(bad.to_str().unwrap()).is_err());
        assert!(load(dir.join("missing.obj").to_str().unwrap()).is_err());
        assert!(load("builtin:nope").is_err());
        assert!(load("builtin:tetra").unwrap().builtin.is_some());
        assert!(load("builtin:tetra").unwrap().materials.is_empty());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn loads_materials_and_survives_a_missing_mtl() {
        let dir = std::env::temp_dir().join(format!("sheaf-cli-mtl-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let obj = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
                   usemtl glass\nf 1 2 3\nf 1 3 4\nusemtl mirror\nf 1 2 4\nusemtl nope\nf 2 3 4\n\
                   usemtl plain\nf 1 2 3\nusemtl plain\nf 1 3 4\n";
        std::fs::write(dir.join("a.obj"), obj).unwrap();
        std::fs::write(
            dir.join("m.mtl"),
            "newmtl glass\nKd 0.1 0.2 0.3\nd 0.25\nNi 1.33\nillum 7\nKs 0.9 0.9 0.9\n\
             newmtl mirror\nKd 2 0.5 0.5\nKs 0.2 0.7 0.1\nillum 3\n\
             newmtl plain\nKd 0.5 0.5 0.5\nKs 1 1 1\nillum 2\nTr 0.4\n",
        )
        .unwrap();
        let l = load(dir.join("a.obj").to_str().unwrap()).unwrap();
        let find = |name: &str| {
            ["glass", "mirror", "plain"]
                .iter()
                .position(|&n| n == name)
                .unwrap()
        };
        assert_eq!(l.materials.len(), 3);
        let glass = l.materials[find("glass")];
        assert_eq!(
            (glass.diffuse, glass.transmit, glass.ior),
            ([0.1, 0.2, 0.3], 0.75, 1.33)
        );
        assert!(
            (glass.reflect - 0.25).abs() < 1e-6,
            "clamped to 1 - transmit: {glass:?}"
        );
        let mirror = l.materials[find("mirror")];
        assert_eq!(
            mirror,
            Material {
                diffuse: [1.0, 0.5, 0.5],
                reflect: 0.7,
                transmit: 0.0,
                ior: 1.0
            }
        );
        let plain = l.materials[find("plain")];
        assert_eq!(
            plain,
            Material {
                diffuse: [0.5; 3],
                reflect: 0.0,
                transmit: 0.4,
                ior: 1.5
            }
        );
        let r = |first, name: &str| MaterialRange {
            first,
            material: find(name) as u32,
        };
        assert_eq!(
            l.ranges,
            [
                r(0, "glass"),
                r(2, "mirror"),
                MaterialRange {
                    first: 3,
                    material: DEFAULT_MATERIAL
                },
                r(4, "plain")
            ]
        );
        l.materials().validate().unwrap();
        // Without the .mtl: a warning, every surface default.
        std::fs::remove_file(dir.join("m.mtl")).unwrap();
        let l = load(dir.join("a.obj").to_str().unwrap()).unwrap();
        assert_eq!(
            (l.indices.len() / 3, l.materials.len(), l.ranges.len()),
            (6, 0, 0)
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
