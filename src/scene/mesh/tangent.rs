//! Tangents for normal mapping, generated with MikkTSpace when a file has none.
//!
//! glTF 2.0 §3.7.2.1: "When tangents are not specified, client implementations SHOULD
//! calculate tangents using default MikkTSpace algorithms with the specified vertex positions,
//! normals, and texture coordinates associated with the normal texture." MikkTSpace (the
//! `mikktspace` crate, Mikkelsen 2008) gives each triangle corner its tangent; a vertex whose
//! corners disagree is split so that each copy carries one tangent, as glTF's per-vertex
//! TANGENT attribute must.

use glam::{Vec2, Vec3, Vec4};
use std::collections::HashMap;

/// A triangle list with per-corner tangent output, as `mikktspace` walks it.
struct Corners<'a> {
    positions: &'a [Vec3],
    normals: &'a [Vec3],
    uvs: &'a [Vec2],
    triangles: &'a [[u32; 3]],
    out: Vec<Vec4>,
}

impl mikktspace::Geometry for Corners<'_> {
    fn num_faces(&self) -> usize {
        self.triangles.len()
    }
    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }
    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.positions[self.triangles[face][vert] as usize].to_array()
    }
    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        self.normals[self.triangles[face][vert] as usize].to_array()
    }
    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        // glTF's v points down the image while a normal map's +Y (green) points up it
        // (§3.9.3: "+X is right and +Y is up"): MikkTSpace's bitangent follows +v, so it is
        // given 1 − v to make w·(N × T) point up the image, as TANGENT's w must.
        let uv = self.uvs[self.triangles[face][vert] as usize];
        [uv.x, 1.0 - uv.y]
    }
    fn set_tangent_encoded(&mut self, tangent: [f32; 4], face: usize, vert: usize) {
        self.out[face * 3 + vert] = Vec4::from_array(tangent);
    }
}

/// MikkTSpace tangents (xyz unit, w = ±1 the bitangent's sign, as glTF's TANGENT) for a
/// triangle list. Vertices whose corners get different tangents are split: the returned
/// `split` lists, for each vertex appended after the first `positions.len()`, the vertex it
/// copies, and `triangles` is rewritten to use the copies. Corners MikkTSpace leaves without a
/// tangent (degenerate uvs) get one orthogonal to the normal.
pub(super) fn generate(
    positions: &[Vec3],
    normals: &[Vec3],
    uvs: &[Vec2],
    triangles: &mut [[u32; 3]],
) -> (Vec<Vec4>, Vec<u32>) {
    let n = positions.len();
    let valid = normals.len() == n
        && uvs.len() == n
        && triangles
            .iter()
            .all(|t| t.iter().all(|&i| (i as usize) < n));
    let fallback = |i: usize| {
        let nrm = normals.get(i).copied().unwrap_or(Vec3::Z);
        nrm.any_orthonormal_vector().extend(1.0)
    };
    if !valid {
        return ((0..n).map(fallback).collect(), Vec::new());
    }
    let mut g = Corners {
        positions,
        normals,
        uvs,
        triangles,
        out: vec![Vec4::ZERO; triangles.len() * 3],
    };
    let ok = mikktspace::generate_tangents(&mut g);
    let corners = g.out;
    let mut tangents: Vec<Option<Vec4>> = vec![None; n];
    let mut split: Vec<u32> = Vec::new();
    let mut copies: HashMap<(u32, [u32; 4]), u32> = HashMap::new();
    for (f, tri) in triangles.iter_mut().enumerate() {
        for (k, vertex) in tri.iter_mut().enumerate() {
            let v = *vertex as usize;
            let t = corners[f * 3 + k];
            let t = if ok && t.is_finite() && t.truncate().length_squared() > 0.5 {
                t
            } else {
                fallback(v)
            };
            match tangents[v] {
                None => tangents[v] = Some(t),
                Some(have) if have == t => {}
                Some(_) => {
                    let key = (*vertex, t.to_array().map(f32::to_bits));
                    let copy = *copies.entry(key).or_insert_with(|| {
                        split.push(*vertex);
                        tangents.push(Some(t));
                        (tangents.len() - 1) as u32
                    });
                    *vertex = copy;
                }
            }
        }
    }
    let tangents = tangents
        .into_iter()
        .enumerate()
        .map(|(i, t)| t.unwrap_or_else(|| fallback(i)))
        .collect();
    (tangents, split)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quad_mapped_along_x_has_tangent_x() {
        // u grows along +x, v along −y (glTF's v points down the image, so the image's up is
        // +y): T = +x and, with N = +z, B = w·(N × T) = w·(+y) must point up the image, w = 1.
        let positions = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let normals = [Vec3::Z; 4];
        let uvs = [
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 0.0),
        ];
        let mut tris = [[0, 1, 2], [0, 2, 3]];
        let (t, split) = generate(&positions, &normals, &uvs, &mut tris);
        assert!(split.is_empty());
        for t in t {
            assert!((t.truncate() - Vec3::X).length() < 1e-5, "{t}");
            assert_eq!(t.w, 1.0);
        }
    }

    #[test]
    fn bad_input_gets_orthogonal_tangents() {
        let positions = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let normals = [Vec3::Z; 3];
        // all uvs equal: no tangent direction exists
        let uvs = [Vec2::ZERO; 3];
        let mut tris = [[0, 1, 2]];
        let (t, _) = generate(&positions, &normals, &uvs, &mut tris);
        for t in t {
            assert!(t.truncate().dot(Vec3::Z).abs() < 1e-6 && t.is_finite());
        }
        let mut bad = [[0, 1, 7]];
        let (t, split) = generate(&positions, &normals, &uvs, &mut bad);
        assert_eq!((t.len(), split.len()), (3, 0));
    }
}
