//! Two helpers on poses shared by every layer: applying a rigid transform to a vector, and
//! re-normalising a pose's rotation.

use dynapix_geometry::Se3;
use nalgebra::{Point3, Vector3};

/// Applies a rigid transform to a point given as a vector.
pub fn transform(t: &Se3, p: &Vector3<f64>) -> Vector3<f64> {
    t.transform_point(&Point3::from(*p)).coords
}

/// Re-normalises the rotation quaternion. Products of poses (motion model: velocity ·
/// last pose, velocity = current · last⁻¹) feed rounding errors of the quaternion norm back
/// into themselves and make them grow geometrically, so every pose the tracker keeps is
/// normalised.
pub fn normalized(t: &Se3) -> Se3 {
    Se3::from_parts(
        t.translation,
        nalgebra::UnitQuaternion::new_normalize(t.rotation.into_inner()),
    )
}
