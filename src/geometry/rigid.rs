//! 3D rigid and affine transforms: 4x4 row-major matrices acting on column points (x, y, z, 1).
//!
//! Named by their frames (docs/frames.md): `build_from_ct` maps CT physical mm to build mm, so
//! `build_from_ct.apply(p_ct)` is a build point and `build_from_ct.inverse()` is `ct_from_build`.

use serde::{Deserialize, Serialize};

/// A row-major 4x4 matrix.
pub type Matrix4 = [[f64; 4]; 4];

const IDENTITY: Matrix4 = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Largest |RᵀR − I| entry accepted as a rotation: loose enough for matrices written with a few
/// decimals, tight enough to refuse a scale, a shear or a mistyped entry.
pub const ROTATION_TOLERANCE: f64 = 1e-4;

/// Why a 4x4 matrix is not the transform it should be.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TransformError {
    #[error("the 4x4 matrix has a non-finite entry")]
    NotFinite,
    #[error("the bottom row of the 4x4 matrix is {0:?}, not [0, 0, 0, 1]")]
    NotHomogeneous([f64; 4]),
    #[error(
        "the upper-left 3x3 of the matrix is not a rotation (largest |RᵀR − I| entry \
         {deviation:.2e}, determinant {det:.6}): a rigid transform has no scale, shear or mirror"
    )]
    NotRotation { deviation: f64, det: f64 },
}

fn check_affine(m: &Matrix4) -> Result<(), TransformError> {
    if m.iter().flatten().any(|v| !v.is_finite()) {
        return Err(TransformError::NotFinite);
    }
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(TransformError::NotHomogeneous(m[3]));
    }
    Ok(())
}

/// `m` applied to a point: rows 0..3 of `m · (p, 1)`.
#[inline]
fn apply(m: &Matrix4, p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
}

/// A rotation and a translation: `p ↦ R·p + t`, stored as the 4x4 `[[R, t], [0, 1]]`.
///
/// Serialises as the plain `[[f64; 4]; 4]` (rows); deserialising checks that it is rigid.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "Matrix4", into = "Matrix4")]
pub struct Rigid3 {
    m: Matrix4,
}

impl Rigid3 {
    pub const IDENTITY: Rigid3 = Rigid3 { m: IDENTITY };

    /// The rigid transform of a 4x4 matrix, checked: finite, bottom row `[0, 0, 0, 1]` and a
    /// proper rotation within [`ROTATION_TOLERANCE`].
    pub fn from_matrix(m: Matrix4) -> Result<Self, TransformError> {
        check_affine(&m)?;
        let mut deviation: f64 = 0.0;
        for i in 0..3 {
            for j in 0..3 {
                let dot: f64 = (0..3).map(|k| m[k][i] * m[k][j]).sum();
                let want = if i == j { 1.0 } else { 0.0 };
                deviation = deviation.max((dot - want).abs());
            }
        }
        let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        if deviation > ROTATION_TOLERANCE || det <= 0.0 {
            return Err(TransformError::NotRotation { deviation, det });
        }
        Ok(Self { m })
    }

    /// A matrix the caller knows to be rigid (e.g. built from a rotation it computed); nothing
    /// is checked.
    pub fn from_matrix_unchecked(m: Matrix4) -> Self {
        Self { m }
    }

    /// The rotation `r` (rows) followed by the translation `t`.
    pub fn from_rotation_translation(r: [[f64; 3]; 3], t: [f64; 3]) -> Self {
        let mut m = IDENTITY;
        for i in 0..3 {
            m[i][..3].copy_from_slice(&r[i]);
            m[i][3] = t[i];
        }
        Self { m }
    }

    /// The 4x4 matrix, row-major.
    pub fn matrix(&self) -> &Matrix4 {
        &self.m
    }

    /// The translation column.
    pub fn translation(&self) -> [f64; 3] {
        [self.m[0][3], self.m[1][3], self.m[2][3]]
    }

    /// `R·p + t`.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        apply(&self.m, p)
    }

    /// The inverse transform: Rᵀ and −Rᵀt.
    pub fn inverse(&self) -> Rigid3 {
        let t = &self.m;
        let mut inv = [[0.0; 4]; 4];
        for r in 0..3 {
            for c in 0..3 {
                inv[r][c] = t[c][r];
            }
            inv[r][3] = -(0..3).map(|c| t[c][r] * t[c][3]).sum::<f64>();
        }
        inv[3][3] = 1.0;
        Rigid3 { m: inv }
    }
}

impl Default for Rigid3 {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl TryFrom<Matrix4> for Rigid3 {
    type Error = TransformError;
    fn try_from(m: Matrix4) -> Result<Self, TransformError> {
        Self::from_matrix(m)
    }
}

impl From<Rigid3> for Matrix4 {
    fn from(t: Rigid3) -> Matrix4 {
        t.m
    }
}

/// A general affine transform `p ↦ A·p + b` (e.g. a CT's voxel index → mm with anisotropic or
/// sheared axes), stored as the 4x4 `[[A, b], [0, 1]]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine3 {
    m: Matrix4,
}

impl Affine3 {
    pub const IDENTITY: Affine3 = Affine3 { m: IDENTITY };

    /// The affine transform of a 4x4 matrix, checked: finite, bottom row `[0, 0, 0, 1]`.
    pub fn from_matrix(m: Matrix4) -> Result<Self, TransformError> {
        check_affine(&m)?;
        Ok(Self { m })
    }

    /// The 4x4 matrix, row-major.
    pub fn matrix(&self) -> &Matrix4 {
        &self.m
    }

    /// `A·p + b`.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        apply(&self.m, p)
    }

    /// The inverse transform, if `A` is invertible.
    pub fn inverse(&self) -> Option<Affine3> {
        let a = nalgebra::Matrix4::from_fn(|r, c| self.m[r][c]);
        let inv = a.try_inverse()?;
        Some(Affine3 {
            m: std::array::from_fn(|r| std::array::from_fn(|c| inv[(r, c)])),
        })
    }
}

impl Default for Affine3 {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl From<Rigid3> for Affine3 {
    fn from(t: Rigid3) -> Affine3 {
        Affine3 { m: t.m }
    }
}

impl From<Affine3> for Matrix4 {
    fn from(t: Affine3) -> Matrix4 {
        t.m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 30° about z, then a translation.
    fn sample() -> Matrix4 {
        let (s, c) = 30f64.to_radians().sin_cos();
        [
            [c, -s, 0.0, 1.5],
            [s, c, 0.0, -2.0],
            [0.0, 0.0, 1.0, 0.25],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }

    #[test]
    fn rigid_apply_and_inverse_round_trip() {
        let t = Rigid3::from_matrix(sample()).expect("rigid");
        let p = [0.3, -7.0, 12.5];
        let q = t.apply(p);
        let (s, c) = 30f64.to_radians().sin_cos();
        assert_eq!(q, [c * 0.3 + s * 7.0 + 1.5, s * 0.3 - c * 7.0 - 2.0, 12.75]);
        let back = t.inverse().apply(q);
        for a in 0..3 {
            assert!((back[a] - p[a]).abs() < 1e-12, "{back:?}");
        }
        assert_eq!(t.translation(), [1.5, -2.0, 0.25]);
        assert_eq!(t.inverse().matrix()[3], [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(Rigid3::IDENTITY.apply(p), p);
    }

    #[test]
    fn rigid_refuses_scale_mirror_and_bad_rows() {
        let mut m = sample();
        m[0][0] *= 1.01;
        assert!(matches!(
            Rigid3::from_matrix(m),
            Err(TransformError::NotRotation { .. })
        ));
        let mut m = sample();
        m[2][2] = -1.0;
        let e = Rigid3::from_matrix(m).expect_err("mirror");
        assert!(e.to_string().contains("determinant"), "{e}");
        let mut m = sample();
        m[3][0] = 0.5;
        assert!(matches!(
            Rigid3::from_matrix(m),
            Err(TransformError::NotHomogeneous(_))
        ));
        let mut m = sample();
        m[1][3] = f64::NAN;
        assert_eq!(Rigid3::from_matrix(m), Err(TransformError::NotFinite));
    }

    #[test]
    fn rigid_serialises_as_a_plain_matrix() {
        #[derive(Serialize, Deserialize)]
        struct WithT {
            transform: Rigid3,
        }
        #[derive(Serialize)]
        struct WithM {
            transform: Matrix4,
        }
        let m = sample();
        let typed = toml::to_string(&WithT {
            transform: Rigid3::from_matrix(m).expect("rigid"),
        })
        .expect("toml");
        let plain = toml::to_string(&WithM { transform: m }).expect("toml");
        assert_eq!(typed, plain);
        let back: WithT = toml::from_str(&plain).expect("parse");
        assert_eq!(back.transform.matrix(), &m);
        let mut scaled = m;
        scaled[0][0] *= 2.0;
        let scaled = toml::to_string(&WithM { transform: scaled }).expect("toml");
        assert!(toml::from_str::<WithT>(&scaled).is_err(), "{scaled}");
    }

    #[test]
    fn affine_inverse_and_singular() {
        let m = [
            [0.05, 0.0, 0.0, -3.0],
            [0.0, 0.0, 0.07, 1.0],
            [0.0, -0.05, 0.0, 40.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let a = Affine3::from_matrix(m).expect("affine");
        let inv = a.inverse().expect("invertible");
        let p = [10.0, 20.0, 30.0];
        let back = inv.apply(a.apply(p));
        for k in 0..3 {
            assert!((back[k] - p[k]).abs() < 1e-9, "{back:?}");
        }
        let mut s = m;
        s[2][1] = 0.0;
        assert!(Affine3::from_matrix(s).expect("affine").inverse().is_none());
        let r = Rigid3::from_matrix(IDENTITY).expect("rigid");
        assert_eq!(Affine3::from(r), Affine3::IDENTITY);
    }
}
