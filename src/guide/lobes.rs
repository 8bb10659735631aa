//! The guide's lobes as the build stores them: importance nodes, power-cosine lobes toward
//! importance points (eq. 162-163), portal rectangles, and the per-node plan of which lobes
//! share a target or a portal, worked out once at build so a query need not.

use super::settings::LobeAim;
use crate::math::{warp, Vec2, Vec3};

/// Most lobes a query holds (the upper bound of `max_lobes`).
pub const MAX_LOBES: usize = 8;

/// A node whose mapped surfaces receive emitted power.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportanceNode {
    /// Filtered skeleton node index.
    pub node: u32,
    /// Estimated emitted power arriving on its surfaces (luminance, W), eq. 176.
    pub power: f32,
}

/// A lobe target of one node: toward the importance point of one importance node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuideLobe {
    /// Skeleton importance point (eq. 162), world space.
    pub point: Vec3,
    /// Smallest maximal-ball radius along the visible prefix of the path (world units).
    pub radius: f32,
    /// Selection probability among the node's lobes (eq. 165 over the lobes kept, or the
    /// learned one with `lobe_weights=learned`; 0: the lobe is never used).
    pub probability: f32,
    /// Index into [`SkeletonGuide::importance_nodes`]: the most probable of the importance
    /// nodes whose lobes coincide (same point and radius) and were merged into this one.
    pub importance: u32,
    /// Graph distance to that importance node.
    pub distance: f32,
    /// The path's bottleneck (module docs, "Aiming through the opening"): position of the
    /// node of smallest maximal ball on the shortest path to the importance node, the node
    /// itself excluded, and the radius of the disc with the area of the opening there
    /// (measured across the path, at least the ball's). Equal to `point` and `radius` when
    /// the path has no node after this one.
    pub opening: Vec3,
    pub opening_radius: f32,
    /// With `aim=portal`: the opening's cross-section at the bottleneck as a rectangle.
    pub portal: Option<Portal>,
}

impl GuideLobe {
    /// Whether the lobe's path has a bottleneck distinct from its importance point (module
    /// docs, "Aiming through the opening").
    pub fn has_opening(&self) -> bool {
        self.opening != self.point || self.opening_radius != self.radius
    }
}

/// A planar rectangle across a path at its bottleneck: `centre ± half.x u ± half.y v`, with
/// `u`, `v` orthonormal (the principal axes of the opening's outline) and normal `u × v`
/// along the path.
#[derive(Clone, Copy, Debug, PartialEq)]
///
/// The fields are private: `frame` is derived from the others when the portal is made, and a
/// portal changed afterwards would sample with a stale frame.
pub struct Portal {
    centre: Vec3,
    u: Vec3,
    v: Vec3,
    half: Vec2,
    /// The rectangle's corner and frame, set up once for every point that sees it (a function
    /// of the fields above; None for a rectangle without area, which no point sees).
    frame: Option<warp::RectangleFrame>,
}

impl Portal {
    pub(super) fn new(centre: Vec3, u: Vec3, v: Vec3, half: Vec2) -> Portal {
        let corner = centre - half.x * u - half.y * v;
        let size = 2.0 * half;
        Portal {
            centre,
            u,
            v,
            half,
            frame: warp::RectangleFrame::new(corner, u, v, size.x, size.y),
        }
    }

    /// The rectangle as seen from `p`, for sampling uniformly in solid angle (None where p is
    /// in its plane).
    pub fn seen_from(&self, p: Vec3) -> Option<warp::SphericalRectangle> {
        self.frame.as_ref()?.seen_from(p)
    }

    /// [`Self::seen_from`] written into `rect` (false where it gives None).
    #[inline]
    pub(super) fn seen_from_into(&self, p: Vec3, rect: &mut warp::SphericalRectangle) -> bool {
        self.frame
            .as_ref()
            .is_some_and(|frame| frame.seen_from_into(p, rect))
    }
}

/// What [`GuideQuery::init`] needs of a node's lobe beyond the lobe itself, found once at build
/// rather than searched per lobe and vertex: which of the node's distinct lobe targets
/// (openings and importance points, equal as `Vec3`s) and distinct portals (equal as
/// `Portal`s) the lobe's are. The answers (the shadow ray, the rectangle) stay per point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct LobePlan {
    /// Whether the lobe aims through its opening ([`GuideLobe::has_opening`] and an aim other
    /// than `point`).
    pub(super) through_opening: bool,
    /// Slots of the lobe's opening and importance point among the node's distinct targets:
    /// the index of the first target of the node equal to each, in the order opening, point
    /// of lobe 0, then of lobe 1, ...
    pub(super) opening_slot: u8,
    pub(super) point_slot: u8,
    /// With a portal: the index of the node's first lobe whose portal equals this one's.
    pub(super) portal_slot: Option<u8>,
}

/// The plans of one node's lobes ([`LobePlan`]).
pub(super) fn plan_lobes(lobes: &[GuideLobe], aim: LobeAim) -> Vec<LobePlan> {
    debug_assert!(lobes.len() <= MAX_LOBES);
    let mut targets: Vec<Vec3> = Vec::with_capacity(2 * lobes.len());
    let mut slot_of = |t: Vec3| -> u8 {
        match targets.iter().position(|&seen| seen == t) {
            Some(i) => i as u8,
            None => {
                targets.push(t);
                (targets.len() - 1) as u8
            }
        }
    };
    lobes
        .iter()
        .enumerate()
        .map(|(j, lobe)| LobePlan {
            through_opening: lobe.has_opening() && aim != LobeAim::ImportancePoint,
            opening_slot: slot_of(lobe.opening),
            point_slot: slot_of(lobe.point),
            portal_slot: lobe.portal.as_ref().map(|portal| {
                lobes[..=j]
                    .iter()
                    .position(|l| l.portal.as_ref() == Some(portal))
                    .unwrap_or(j) as u8
            }),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Frame, Rng};

    /// A portal's rectangle seen from a point is, bit for bit, the spherical rectangle of the
    /// corner and sides its centre and half sizes give (so `Portal::new` keeps the frame of
    /// its own rectangle), degenerate ones and points in the plane included.
    #[test]
    fn portals_see_points_as_rectangles_set_up_there() {
        let mut rng = Rng::new(11, 4);
        let (mut seen, mut unseen) = (0, 0);
        let mut slot: Option<warp::SphericalRectangle> = None;
        for i in 0..2000 {
            let u = warp::uniform_sphere(rng.uniform2());
            let v = Frame::from_z(u).s;
            let centre = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 8.0 - 4.0;
            let mut half = Vec2::new(rng.uniform(), rng.uniform()) * 2.0;
            if i % 50 == 0 {
                half.x = 0.0;
            }
            let portal = Portal::new(centre, u, v, half);
            for _ in 0..4 {
                let mut p = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 8.0 - 4.0;
                if rng.uniform() < 0.2 {
                    // In the rectangle's plane.
                    p = centre + (rng.uniform() - 0.5) * u + (rng.uniform() - 0.5) * v;
                }
                let corner = centre - half.x * u - half.y * v;
                let size = 2.0 * half;
                let fresh = warp::SphericalRectangle::new(p, corner, u, v, size.x, size.y);
                let kept = portal.seen_from(p);
                assert_eq!(
                    format!("{kept:?}"),
                    format!("{fresh:?}"),
                    "portal {i} from {p}"
                );
                // Set up in place, in a slot that held the last point's rectangle (its angles
                // computed): the same rectangle, nothing of the last one kept.
                if let Some(old) = &slot {
                    old.solid_angle();
                }
                let mut reused = slot.take().unwrap_or_else(warp::SphericalRectangle::empty);
                let set_up = portal.seen_from_into(p, &mut reused);
                assert_eq!(set_up, kept.is_some(), "portal {i} from {p}");
                if set_up {
                    assert_eq!(
                        format!("{:?}", Some(&reused)),
                        format!("{:?}", kept.as_ref())
                    );
                    slot = Some(reused);
                }
                match (kept, fresh) {
                    (Some(a), Some(b)) => {
                        seen += 1;
                        let u = rng.uniform2();
                        let w = a.sample(u);
                        assert_eq!(w.to_array(), b.sample(u).to_array());
                        assert_eq!(a.pdf(w).to_bits(), b.pdf(w).to_bits());
                    }
                    _ => unseen += 1,
                }
            }
        }
        assert!(seen > 5000 && unseen > 400, "{seen} seen, {unseen} not");
    }

    #[test]
    fn lobe_plans_group_equal_targets_and_portals() {
        // Lobes drawn from small pools, so that targets and portals repeat within a node
        // (openings equal to points of other lobes, signed zeros, NaN: equal as the query's
        // `==` has them, never for NaN).
        let mut rng = Rng::new(12, 2);
        let targets = [
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(-0.0, 0.0, 1.0),
            Vec3::new(f32::NAN, 0.0, 0.0),
            Vec3::new(4.0, -1.0, 0.5),
        ];
        let portals = [
            None,
            Some(Portal::new(
                Vec3::ZERO,
                Vec3::X,
                Vec3::Y,
                Vec2::new(1.0, 2.0),
            )),
            Some(Portal::new(
                Vec3::ONE,
                Vec3::Y,
                Vec3::Z,
                Vec2::new(0.5, 0.5),
            )),
            Some(Portal::new(
                Vec3::ONE,
                Vec3::Y,
                Vec3::Z,
                Vec2::new(f32::NAN, 0.5),
            )),
        ];
        let mut shared = [0usize; 2];
        for _ in 0..3000 {
            let n = 1 + (rng.uniform() * MAX_LOBES as f32) as usize;
            let pick = |rng: &mut Rng| targets[(rng.uniform() * 5.0) as usize % 5];
            let lobes: Vec<GuideLobe> = (0..n.min(MAX_LOBES))
                .map(|i| GuideLobe {
                    point: pick(&mut rng),
                    radius: if rng.uniform() < 0.5 { 1.0 } else { 2.0 },
                    probability: 0.1,
                    importance: i as u32,
                    distance: 1.0,
                    opening: pick(&mut rng),
                    opening_radius: 1.0,
                    portal: portals[(rng.uniform() * 4.0) as usize % 4],
                })
                .collect();
            for aim in [LobeAim::ImportancePoint, LobeAim::Opening, LobeAim::Portal] {
                let plans = plan_lobes(&lobes, aim);
                assert_eq!(plans.len(), lobes.len());
                // Every target occurrence with its slot, by brute force over all pairs.
                let occurrences: Vec<(Vec3, u8)> = lobes
                    .iter()
                    .zip(&plans)
                    .flat_map(|(l, p)| [(l.opening, p.opening_slot), (l.point, p.point_slot)])
                    .collect();
                for (a, &(ta, sa)) in occurrences.iter().enumerate() {
                    assert!((sa as usize) < 2 * MAX_LOBES);
                    for &(tb, sb) in &occurrences[a + 1..] {
                        assert_eq!(sa == sb, ta == tb, "{ta} {tb}: slots {sa} {sb}");
                        shared[0] += usize::from(sa == sb);
                    }
                }
                for (j, (l, p)) in lobes.iter().zip(&plans).enumerate() {
                    let wanted_opening = l.has_opening() && aim != LobeAim::ImportancePoint;
                    assert_eq!(p.through_opening, wanted_opening);
                    assert_eq!(p.portal_slot.is_some(), l.portal.is_some());
                    let Some(slot) = p.portal_slot else { continue };
                    // The first lobe with an equal portal (itself when none, or NaN).
                    let first = (0..j)
                        .find(|&k| lobes[k].portal.is_some() && lobes[k].portal == l.portal)
                        .unwrap_or(j);
                    assert_eq!(slot as usize, first, "lobe {j}");
                    shared[1] += usize::from(first < j);
                }
            }
        }
        // Both kinds of sharing happened.
        assert!(shared[0] > 1000 && shared[1] > 1000, "{shared:?}");
    }
}
