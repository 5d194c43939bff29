//! Minimal 3-D linear algebra in `f64`: just what forward kinematics and the
//! local-frame features need. Matrices are row-major and act on column vectors.

/// A 3-vector.
pub type Vec3 = [f64; 3];

/// A 3×3 matrix, row-major, acting on column vectors (`v' = M v`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mat3(pub [[f64; 3]; 3]);

/// A rotation axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Axis {
    /// The x axis.
    X,
    /// The y axis.
    Y,
    /// The z axis.
    Z,
}

impl Mat3 {
    /// The identity matrix.
    pub const IDENTITY: Mat3 = Mat3([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);

    /// Right-handed rotation by `radians` about `axis`.
    pub fn rotation(axis: Axis, radians: f64) -> Mat3 {
        let (s, c) = radians.sin_cos();
        match axis {
            Axis::X => Mat3([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]),
            Axis::Y => Mat3([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]),
            Axis::Z => Mat3([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
        }
    }

    /// Rotation from Euler angles given in the order they are *listed*:
    /// `R = R(a0) · R(a1) · R(a2)`, i.e. the first listed is the outermost
    /// (BVH convention for `CHANNELS … Zrotation Yrotation Xrotation`).
    pub fn euler_listed(axes: &[Axis], radians: &[f64]) -> Mat3 {
        axes.iter()
            .zip(radians)
            .fold(Mat3::IDENTITY, |m, (&a, &r)| m.mul(&Mat3::rotation(a, r)))
    }

    /// Rotation from Euler angles given in the order they are *applied*:
    /// `R = R(a_n) · … · R(a1) · R(a0)` (ASF/AMC convention: `axis … XYZ` and
    /// `dof rx ry rz` rotate about x first, then y, then z).
    pub fn euler_applied(axes: &[Axis], radians: &[f64]) -> Mat3 {
        axes.iter()
            .zip(radians)
            .fold(Mat3::IDENTITY, |m, (&a, &r)| Mat3::rotation(a, r).mul(&m))
    }

    /// Matrix product `self · rhs`.
    pub fn mul(&self, rhs: &Mat3) -> Mat3 {
        let a = &self.0;
        let b = &rhs.0;
        let mut out = [[0.0; 3]; 3];
        for (i, row) in out.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
            }
        }
        Mat3(out)
    }

    /// Matrix-vector product `self · v`.
    pub fn apply(&self, v: Vec3) -> Vec3 {
        let a = &self.0;
        [
            a[0][0] * v[0] + a[0][1] * v[1] + a[0][2] * v[2],
            a[1][0] * v[0] + a[1][1] * v[1] + a[1][2] * v[2],
            a[2][0] * v[0] + a[2][1] * v[1] + a[2][2] * v[2],
        ]
    }

    /// The transpose (the inverse of a rotation).
    pub fn transpose(&self) -> Mat3 {
        let a = &self.0;
        Mat3([
            [a[0][0], a[1][0], a[2][0]],
            [a[0][1], a[1][1], a[2][1]],
            [a[0][2], a[1][2], a[2][2]],
        ])
    }
}

/// `a + b`.
#[inline]
pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a - b`.
#[inline]
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `s · a`.
#[inline]
pub fn scale(a: Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// Dot product.
#[inline]
pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Cross product `a × b`.
#[inline]
pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Euclidean length.
#[inline]
pub fn norm(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        norm(sub(a, b)) < 1e-12
    }

    #[test]
    fn rotations_are_right_handed() {
        let q = std::f64::consts::FRAC_PI_2;
        assert!(close(
            Mat3::rotation(Axis::Z, q).apply([1.0, 0.0, 0.0]),
            [0.0, 1.0, 0.0]
        ));
        assert!(close(
            Mat3::rotation(Axis::X, q).apply([0.0, 1.0, 0.0]),
            [0.0, 0.0, 1.0]
        ));
        assert!(close(
            Mat3::rotation(Axis::Y, q).apply([0.0, 0.0, 1.0]),
            [1.0, 0.0, 0.0]
        ));
    }

    #[test]
    fn listed_and_applied_orders_are_reverses() {
        let axes = [Axis::Z, Axis::Y, Axis::X];
        let r = [0.3, -0.7, 1.1];
        let listed = Mat3::euler_listed(&axes, &r);
        let rev_axes = [Axis::X, Axis::Y, Axis::Z];
        let rev_r = [1.1, -0.7, 0.3];
        let applied = Mat3::euler_applied(&rev_axes, &rev_r);
        for i in 0..3 {
            for j in 0..3 {
                assert!((listed.0[i][j] - applied.0[i][j]).abs() < 1e-12);
            }
        }
    }
}
