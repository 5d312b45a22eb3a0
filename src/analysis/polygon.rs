//! Convex polygons in the plane: areas, containment and clipping by half-planes.

use nalgebra::Vector2;

/// Why vertices do not make a convex polygon.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PolygonError {
    #[error("a vertex is not a number")]
    NotANumber,
    #[error("{0} vertices: a polygon needs 3 or more")]
    TooFew(usize),
    #[error("the vertices enclose no area")]
    NoArea,
    /// The vertex (counted from 1) where the boundary turns the other way, and its position.
    #[error("not convex at vertex {vertex} ({x:.3}, {y:.3}): give a convex polygon in order")]
    NotConvex { vertex: usize, x: f64, y: f64 },
}

/// A convex polygon, vertices counter-clockwise, no three in a row.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvexPolygon {
    vertices: Vec<Vector2<f64>>,
}

fn cross(a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Twice the signed area (positive counter-clockwise).
fn signed_area2(v: &[Vector2<f64>]) -> f64 {
    (0..v.len())
        .map(|i| cross(&v[i], &v[(i + 1) % v.len()]))
        .sum()
}

impl ConvexPolygon {
    /// The polygon of `vertices` (either orientation), or why it is not a convex polygon.
    pub fn new(mut vertices: Vec<Vector2<f64>>) -> Result<ConvexPolygon, PolygonError> {
        if vertices
            .iter()
            .any(|v| !(v.x.is_finite() && v.y.is_finite()))
        {
            return Err(PolygonError::NotANumber);
        }
        // A closing vertex equal to the first is dropped.
        if vertices.len() > 1 && vertices.first() == vertices.last() {
            vertices.pop();
        }
        if vertices.len() < 3 {
            return Err(PolygonError::TooFew(vertices.len()));
        }
        let a2 = signed_area2(&vertices);
        if a2.abs() < 1e-12 {
            return Err(PolygonError::NoArea);
        }
        if a2 < 0.0 {
            vertices.reverse();
        }
        let n = vertices.len();
        for i in 0..n {
            let (a, b, c) = (vertices[i], vertices[(i + 1) % n], vertices[(i + 2) % n]);
            if cross(&(b - a), &(c - b)) < -1e-12 * (b - a).norm() * (c - b).norm() {
                return Err(PolygonError::NotConvex {
                    vertex: (i + 1) % n + 1,
                    x: b.x,
                    y: b.y,
                });
            }
        }
        Ok(ConvexPolygon { vertices })
    }

    pub fn vertices(&self) -> &[Vector2<f64>] {
        &self.vertices
    }

    /// Area, m².
    pub fn area(&self) -> f64 {
        0.5 * signed_area2(&self.vertices)
    }

    /// Whether `p` is inside or on the boundary.
    pub fn contains(&self, p: &Vector2<f64>) -> bool {
        self.edges().all(|(a, b)| cross(&(b - a), &(p - a)) >= 0.0)
    }

    /// Whether `p` is inside and not on the boundary (PedPy's count for the classic density).
    pub fn strictly_contains(&self, p: &Vector2<f64>) -> bool {
        self.edges().all(|(a, b)| cross(&(b - a), &(p - a)) > 0.0)
    }

    fn edges(&self) -> impl Iterator<Item = (Vector2<f64>, Vector2<f64>)> + '_ {
        let n = self.vertices.len();
        (0..n).map(move |i| (self.vertices[i], self.vertices[(i + 1) % n]))
    }

    /// The part where `normal · x <= offset`; None when nothing with area is left.
    pub fn cut(&self, normal: &Vector2<f64>, offset: f64) -> Option<ConvexPolygon> {
        let side = |p: &Vector2<f64>| normal.dot(p) - offset;
        let n = self.vertices.len();
        let mut out = Vec::with_capacity(n + 1);
        for i in 0..n {
            let (a, b) = (self.vertices[i], self.vertices[(i + 1) % n]);
            let (sa, sb) = (side(&a), side(&b));
            if sa <= 0.0 {
                out.push(a);
            }
            if (sa < 0.0 && sb > 0.0) || (sa > 0.0 && sb < 0.0) {
                out.push(a + (b - a) * (sa / (sa - sb)));
            }
        }
        out.dedup_by(|a, b| (*a - *b).norm_squared() < 1e-24);
        if out.len() > 1 && (out[0] - out[out.len() - 1]).norm_squared() < 1e-24 {
            out.pop();
        }
        (out.len() >= 3 && signed_area2(&out) > 1e-12).then_some(ConvexPolygon { vertices: out })
    }

    /// The intersection with another convex polygon; None when it has no area.
    pub fn clip(&self, other: &ConvexPolygon) -> Option<ConvexPolygon> {
        let mut out = self.clone();
        for (a, b) in other.edges() {
            // Inside is to the left of a → b: −(b − a)⊥ · x <= −(b − a)⊥ · a.
            let d = b - a;
            let normal = Vector2::new(d.y, -d.x);
            out = out.cut(&normal, normal.dot(&a))?;
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64) -> Vector2<f64> {
        Vector2::new(x, y)
    }

    #[test]
    fn areas_containment_and_clipping() {
        // Clockwise input is turned round.
        let sq =
            ConvexPolygon::new(vec![v(0.0, 0.0), v(0.0, 2.0), v(2.0, 2.0), v(2.0, 0.0)]).unwrap();
        assert!((sq.area() - 4.0).abs() < 1e-12);
        assert!(sq.contains(&v(0.0, 1.0)) && !sq.strictly_contains(&v(0.0, 1.0)));
        assert!(sq.strictly_contains(&v(1.0, 1.0)) && !sq.contains(&v(2.1, 1.0)));
        let half = sq.cut(&v(1.0, 0.0), 0.5).unwrap();
        assert!((half.area() - 1.0).abs() < 1e-12);
        assert!(sq.cut(&v(1.0, 0.0), -1.0).is_none());
        let moved =
            ConvexPolygon::new(vec![v(1.0, 1.0), v(3.0, 1.0), v(3.0, 3.0), v(1.0, 3.0)]).unwrap();
        assert!((sq.clip(&moved).unwrap().area() - 1.0).abs() < 1e-12);
        let far = ConvexPolygon::new(vec![v(5.0, 5.0), v(6.0, 5.0), v(6.0, 6.0)]).unwrap();
        assert!(sq.clip(&far).is_none());
    }

    #[test]
    fn bad_polygons_are_named() {
        assert!(
            ConvexPolygon::new(vec![v(0.0, 0.0), v(1.0, 0.0)])
                .unwrap_err()
                .to_string()
                .contains("3 or more")
        );
        assert!(
            ConvexPolygon::new(vec![v(0.0, 0.0), v(1.0, 0.0), v(2.0, 0.0)])
                .unwrap_err()
                .to_string()
                .contains("no area")
        );
        let dart = vec![v(0.0, 0.0), v(2.0, 0.0), v(1.0, 0.5), v(1.0, 2.0)];
        assert!(matches!(
            ConvexPolygon::new(dart).unwrap_err(),
            PolygonError::NotConvex { .. }
        ));
        // A closed ring (last = first) is accepted.
        assert!(
            ConvexPolygon::new(vec![v(0.0, 0.0), v(1.0, 0.0), v(0.0, 1.0), v(0.0, 0.0)]).is_ok()
        );
    }
}
