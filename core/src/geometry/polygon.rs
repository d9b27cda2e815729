//! Convex polygon clipping and area (top-view footprints of yaw-oriented boxes).

/// Area of a simple polygon (shoelace formula); absolute value, any winding.
pub fn convex_polygon_area(poly: &[[f64; 2]]) -> f64 {
    if poly.len() < 3 {
        return 0.0;
    }
    let mut s = 0.0;
    for i in 0..poly.len() {
        let a = poly[i];
        let b = poly[(i + 1) % poly.len()];
        s += a[0] * b[1] - b[0] * a[1];
    }
    (s / 2.0).abs()
}

fn signed_area(poly: &[[f64; 2]]) -> f64 {
    let mut s = 0.0;
    for i in 0..poly.len() {
        let a = poly[i];
        let b = poly[(i + 1) % poly.len()];
        s += a[0] * b[1] - b[0] * a[1];
    }
    s / 2.0
}

/// Intersection of two convex polygons (Sutherland-Hodgman: `subject` clipped by each edge of
/// `clip`). Either winding is accepted; the result is counter-clockwise, empty when disjoint.
pub fn convex_polygon_intersection(subject: &[[f64; 2]], clip: &[[f64; 2]]) -> Vec<[f64; 2]> {
    if subject.len() < 3 || clip.len() < 3 {
        return Vec::new();
    }
    let ccw = |p: &[[f64; 2]]| -> Vec<[f64; 2]> {
        let mut v = p.to_vec();
        if signed_area(&v) < 0.0 {
            v.reverse();
        }
        v
    };
    let clip = ccw(clip);
    let mut output = ccw(subject);
    for i in 0..clip.len() {
        if output.is_empty() {
            break;
        }
        let a = clip[i];
        let b = clip[(i + 1) % clip.len()];
        // Inside = left of the directed edge a→b (counter-clockwise clip polygon).
        let side = |p: [f64; 2]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
        let input = std::mem::take(&mut output);
        for j in 0..input.len() {
            let cur = input[j];
            let prev = input[(j + input.len() - 1) % input.len()];
            let (sc, sp) = (side(cur), side(prev));
            if sc >= 0.0 {
                if sp < 0.0 {
                    output.push(intersect(prev, cur, sp, sc));
                }
                output.push(cur);
            } else if sp >= 0.0 {
                output.push(intersect(prev, cur, sp, sc));
            }
        }
    }
    if output.len() < 3 {
        Vec::new()
    } else {
        output
    }
}

fn intersect(p: [f64; 2], q: [f64; 2], sp: f64, sq: f64) -> [f64; 2] {
    let t = sp / (sp - sq);
    [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_clip() {
        let a = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]];
        let b = [[1.0, 1.0], [3.0, 1.0], [3.0, 3.0], [1.0, 3.0]];
        assert!((convex_polygon_area(&convex_polygon_intersection(&a, &b)) - 1.0).abs() < 1e-12);
        // Clockwise input gives the same result.
        let mut bc = b;
        bc.reverse();
        assert!((convex_polygon_area(&convex_polygon_intersection(&a, &bc)) - 1.0).abs() < 1e-12);
        let far = [[5.0, 5.0], [6.0, 5.0], [6.0, 6.0], [5.0, 6.0]];
        assert!(convex_polygon_intersection(&a, &far).is_empty());
    }
}
