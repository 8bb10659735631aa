//! [`GuideQuery`]: the skeleton mixture at one surface point, sampled and evaluated with
//! the exact pdf the host combines with BSDF sampling (eq. 168-170).
//!
//! # Query ([`GuideQuery`])
//!
//! At a surface point x with geometric normal n and incident direction wo, x is mapped to its
//! node; each of the node's lobes points from x to its importance point, with pdf
//! `(s + 1) / (2 pi) max(0, cos)^s` (eq. 163). Two cases the thesis leaves to the
//! implementation (004, "Problems") are resolved *per point*, before any sampling, so that
//! sampling and pdf evaluation always see the same mixture and no bias arises:
//! - an importance direction below the surface (on the other side of n from wo) drops its lobe;
//! - with `visibility_test`, an importance point hidden from x (one shadow ray) drops its lobe.
//!
//! The remaining lobes' probabilities are renormalised (eq. 165 over the lobes kept).
//!
//! A point with no lobe left (no path to any importance node, all directions below the surface
//! or hidden, a point outside the grid) is not guided: its guiding probability is 0 and the host
//! samples the BSDF alone. Delta BSDFs are the host's business: it must not guide there (no
//! mixture with a Dirac lobe has a density), which `path_skeleton` does.
//!
//! What a query costs, kept small without changing the mixture: the node mapping visits only
//! the mapped voxels of the neighbourhood (`analysis::NeighbourMasks`, the same node as
//! eq. 151-155), and takes the neighbour that best faces the normal without a search where it is
//! mapped and clearly ahead (`analysis::map_point`); a target shared by several lobes gets one
//! shadow ray; lobes with the same density at x (the same portal rectangle, or the same target
//! and radius) are one active lobe with their summed probability. Which lobes share a target or
//! a portal is found at build (`LobePlan`), not per vertex; lobes keep only their axis; a portal
//! rectangle computes its angles only for a direction that hits it. With `visibility=voxel` the
//! visibility of each target is decided once per mapped voxel, from its centre, and cached: that
//! changes which lobes apply near silhouettes (still a function of the point, so unbiased), not
//! their shapes.

use std::sync::Arc;

use super::directional::{self, DirectionalTable};
use super::lobes::MAX_LOBES;
use super::mixture::pick_lobe;
use super::settings::{LobeAim, LobeFallback, SkeletonStrength};
use super::skeleton_guide::{GridPoint, SkeletonGuide};
use crate::error::{Error, Result};
use crate::geometry::{offset_ray_origin, Ray, SHADOW_EPSILON};
use crate::math::{warp, Frame, Vec2, Vec3};
use crate::scene::Scene;

/// One lobe of an initialised query.
#[derive(Clone, Debug)]
struct ActiveLobe {
    /// The power-cosine lobe's axis (unit), toward the lobe's target; its frame is set up only
    /// to sample it (the density needs the cosine alone).
    axis: Vec3,
    exponent: f32,
    probability: f32,
    /// Free-space radius and distance the automatic strength was taken from (the lobe's
    /// exponent under any other strength, for the training pass).
    radius: f32,
    distance: f32,
    /// With `aim=portal` where the point sees the bottleneck: directions uniform toward the
    /// opening's rectangle `rect` instead of the power-cosine lobe (`rect` is meaningless
    /// otherwise).
    portal: bool,
    rect: warp::SphericalRectangle,
}

impl ActiveLobe {
    #[inline]
    fn pdf(&self, w: Vec3, exponent: f32) -> f32 {
        if self.portal {
            self.rect.pdf(w)
        } else {
            warp::power_cosine_pdf_cos(w.dot(self.axis), exponent)
        }
    }
}

/// `GuideQuery::lobe_of` of a node lobe that does not apply at the point.
const NOT_ACTIVE: u8 = u8::MAX;

/// An unused lobe slot of a query.
const fn no_lobe() -> ActiveLobe {
    ActiveLobe {
        axis: Vec3::Z,
        exponent: 0.0,
        probability: 0.0,
        radius: 0.0,
        distance: 0.0,
        portal: false,
        rect: warp::SphericalRectangle::empty(),
    }
}

/// The targets a query has aimed at, at one point (see [`GuideQuery::init`]): per slot of the
/// node's distinct targets ([`LobePlan`]), the axis and distance toward it where it applies.
struct Aims<'a> {
    guide: &'a SkeletonGuide,
    scene: &'a Scene,
    p: Vec3,
    p_error: Vec3,
    /// The normal on the incident direction's side.
    side: Vec3,
    voxel: usize,
    /// Shadow rays traced.
    rays: u32,
    /// Bit per slot: aimed at (`known`), and applies (`found`, then `at[slot]` holds it; the
    /// query's storage, left as the last point wrote it elsewhere).
    known: u32,
    found: u32,
    at: &'a mut [(Vec3, f32); 2 * MAX_LOBES],
}

impl Aims<'_> {
    /// Axis and distance toward `target` (slot `slot`) when it is above the surface and, with
    /// the visibility test, seen from p; found once per slot and point. `index` is the
    /// target's number for the voxel's visibility cache (`2 j` the opening of lobe j, `2 j +
    /// 1` its importance point): that of the first lobe that aims at the target at this point.
    #[inline(always)]
    fn aim(&mut self, slot: u8, target: Vec3, index: u32) -> Option<(Vec3, f32)> {
        let bit = 1u32 << slot;
        if self.known & bit != 0 {
            return (self.found & bit != 0).then(|| self.at[slot as usize]);
        }
        self.known |= bit;
        let found = self.aim_at(target, index);
        if let Some(at) = found {
            self.found |= bit;
            self.at[slot as usize] = at;
        }
        found
    }

    /// [`Self::aim`] without the memory (out of line: the memory's test is the common case).
    #[inline(never)]
    fn aim_at(&mut self, target: Vec3, index: u32) -> Option<(Vec3, f32)> {
        let to = target - self.p;
        let distance = to.length();
        let axis = to / distance;
        if !(distance > 0.0 && distance.is_finite()) || axis.dot(self.side) <= 0.0 {
            return None;
        }
        let settings = &self.guide.settings;
        if settings.visibility_test && settings.voxel_visibility {
            // visibility=voxel: what the mapped voxel's centre sees, instead of a ray from p.
            let (sees, traced) = self.guide.voxel_sees(self.scene, self.voxel, index);
            self.rays += traced;
            if !sees {
                return None;
            }
        } else if settings.visibility_test {
            self.rays += 1;
            let origin = offset_ray_origin(self.p, self.p_error, self.side, axis);
            let ray = Ray::new(origin, axis, distance * (1.0 - SHADOW_EPSILON));
            if self.scene.occluded(&ray) {
                return None;
            }
        }
        Some((axis, distance))
    }
}

/// The skeleton sampling distribution at one surface point (eq. 163-167): a mixture of
/// power-cosine lobes. Reusable: one per worker thread, `init` at each point. Holds no
/// reference to the guide, so it can outlive the call that initialised it.
#[derive(Clone, Debug)]
pub struct GuideQuery {
    lobes: [ActiveLobe; MAX_LOBES],
    /// Scratch of `init` ([`Aims`]): kept in the query so that no vertex clears it.
    aimed: [(Vec3, f32); 2 * MAX_LOBES],
    count: usize,
    /// For each of the node's lobes (`SkeletonGuide::lobes`), the active lobe it went into
    /// (merged lobes share one), or `NOT_ACTIVE`: what the training needs to evaluate the
    /// mixture under other selection probabilities.
    lobe_of: [u8; MAX_LOBES],
    c_skel: f32,
    node: Option<u32>,
    /// `directions=learned`: the guide's table and this point's slot in it (`NO_SLOT`: the
    /// lobes, if any, apply). The table is cloned into the query once, not per point.
    directions: Option<Arc<DirectionalTable>>,
    slot: u32,
    /// The strength `init` took the lobes' exponents from (None: no lobes from `init`, or
    /// explicit lobes): under it [`pdf_with_strength`](Self::pdf_with_strength) is `pdf`.
    strength: Option<SkeletonStrength>,
}

/// [`GuideQuery`]'s slot where no learned distribution applies.
const NO_SLOT: u32 = u32::MAX;

impl Default for GuideQuery {
    fn default() -> Self {
        Self::new()
    }
}

impl GuideQuery {
    /// An unguided query (guiding probability 0) until `init` finds lobes.
    pub const fn new() -> Self {
        GuideQuery {
            lobes: [const { no_lobe() }; MAX_LOBES],
            aimed: [(Vec3::ZERO, 0.0); 2 * MAX_LOBES],
            count: 0,
            lobe_of: [NOT_ACTIVE; MAX_LOBES],
            c_skel: 0.0,
            node: None,
            directions: None,
            slot: NO_SLOT,
            strength: None,
        }
    }

    /// A shared unguided query, for integrators without a guide: reading it costs nothing,
    /// while making a query writes its whole lobe array (about 400 bytes, per path).
    pub fn unguided() -> &'static GuideQuery {
        static UNGUIDED: GuideQuery = GuideQuery::new();
        &UNGUIDED
    }

    /// Makes the query unguided (guiding probability 0), as at a point no lobe reaches.
    pub fn clear(&mut self) {
        self.count = 0;
        self.node = None;
        self.slot = NO_SLOT;
        self.strength = None;
    }

    /// A query that samples one learned directional distribution (`guide::directional`) of
    /// bin probabilities `bins` ([`directional::BINS`] of them, >= 0, renormalised), for tests
    /// and hosts. Fails on a wrong count, negative or non-finite entries, no positive entry
    /// or `c_skel` outside [0, 1).
    pub fn with_distribution(c_skel: f32, bins: &[f32]) -> Result<GuideQuery> {
        if !(c_skel.is_finite() && (0.0..1.0).contains(&c_skel)) {
            return Err(Error::invalid(format!("c_skel {c_skel} must be in [0, 1)")));
        }
        let total: f32 = bins.iter().sum();
        if bins.len() != directional::BINS
            || bins.iter().any(|&b| !(b.is_finite() && b >= 0.0))
            || !(total > 0.0 && total.is_finite())
        {
            return Err(Error::invalid(format!(
                "a directional distribution needs {} finite bin weights >= 0, some positive",
                directional::BINS
            )));
        }
        let p: Vec<f32> = bins.iter().map(|b| b / total).collect();
        let p = p.repeat(directional::CLASSES);
        let mut q = GuideQuery::new();
        q.directions = Some(Arc::new(DirectionalTable::new(&[Some(p)])));
        q.slot = 0;
        q.c_skel = c_skel;
        Ok(q)
    }

    /// A query with explicit lobes (axis, exponent, weight), weights renormalised; for hosts
    /// and tests that build their own lobes. Fails on non-finite or zero axes, exponents out
    /// of [0, `MAX_STRENGTH`], negative weights, no positive weight, more than `MAX_LOBES`
    /// lobes or `c_skel` outside [0, 1).
    pub fn with_lobes(c_skel: f32, lobes: &[(Vec3, f32, f32)]) -> Result<GuideQuery> {
        if !(c_skel.is_finite() && (0.0..1.0).contains(&c_skel)) {
            return Err(Error::invalid(format!("c_skel {c_skel} must be in [0, 1)")));
        }
        if lobes.len() > MAX_LOBES {
            return Err(Error::invalid(format!(
                "{} lobes: at most {MAX_LOBES}",
                lobes.len()
            )));
        }
        let total: f32 = lobes.iter().map(|l| l.2).sum();
        let mut q = GuideQuery::new();
        for (i, &(axis, exponent, weight)) in lobes.iter().enumerate() {
            let unit = axis.normalize_or_zero();
            if !crate::math::is_finite3(axis) || unit == Vec3::ZERO {
                return Err(Error::invalid(format!(
                    "lobe {i}: axis {axis} is not a direction"
                )));
            }
            SkeletonStrength::Fixed(exponent).validate()?;
            if !(weight.is_finite() && weight >= 0.0) {
                return Err(Error::invalid(format!(
                    "lobe {i}: weight {weight} must be >= 0"
                )));
            }
            q.lobes[i] = ActiveLobe {
                axis: unit,
                exponent,
                probability: weight / total,
                radius: 0.0,
                distance: 0.0,
                portal: false,
                rect: warp::SphericalRectangle::empty(),
            };
        }
        if !(total > 0.0 && total.is_finite()) {
            return Err(Error::invalid(
                "the lobes need a positive finite total weight",
            ));
        }
        q.count = lobes.len();
        q.c_skel = c_skel;
        Ok(q)
    }

    /// Sets up the distribution at surface point `p` (floating-point error bound `p_error`,
    /// zero if unknown), geometric normal `normal` (either orientation) and incident direction
    /// `wo` (unit, pointing from p back to where the path came from), within `scene` (the
    /// scene the guide was built for; used by the visibility test). Returns the shadow rays
    /// traced. Afterwards [`guiding_probability`](Self::guiding_probability) is the node's
    /// probability (`c_skel`, or the learned one), or 0 when no lobe applies at p (or the
    /// node's probability is 0: then no lobe is set up and no shadow ray traced).
    pub fn init(
        &mut self,
        guide: &SkeletonGuide,
        scene: &Scene,
        p: Vec3,
        p_error: Vec3,
        normal: Vec3,
        wo: Vec3,
    ) -> u32 {
        self.init_at(guide, scene, &guide.locate(p), p_error, normal, wo)
    }

    /// [`init`](Self::init) at the point `at` that [`SkeletonGuide::locate`] found (the host
    /// locates a vertex once, for [`SkeletonGuide::prefetch_at`] and this).
    #[inline]
    pub fn init_at(
        &mut self,
        guide: &SkeletonGuide,
        scene: &Scene,
        at: &GridPoint,
        p_error: Vec3,
        normal: Vec3,
        wo: Vec3,
    ) -> u32 {
        let p = at.point();
        self.count = 0;
        self.node = None;
        self.slot = NO_SLOT;
        self.strength = None;
        self.lobe_of = [NOT_ACTIVE; MAX_LOBES];
        let Some((node, voxel)) = guide.map_located(at, normal, wo) else {
            return 0;
        };
        self.node = Some(node);
        // A node not worth guiding (learned c = 0) costs no lobe work and no shadow ray.
        self.c_skel = guide.guiding_probability(node);
        if self.c_skel <= 0.0 {
            return 0;
        }
        // directions=learned: the node's distribution, or nothing (no lobes either).
        if let Some(table) = &guide.directions {
            let side = if normal.dot(wo) >= 0.0 {
                normal
            } else {
                -normal
            };
            let offset = p - guide.node_positions[node as usize];
            if let Some(slot) = table.slot(node, directional::class_of(side, offset)) {
                if !self
                    .directions
                    .as_ref()
                    .is_some_and(|t| Arc::ptr_eq(t, table))
                {
                    self.directions = Some(table.clone());
                }
                self.slot = slot;
            }
            return 0;
        }
        self.init_lobes(guide, scene, p, p_error, normal, wo, (node, voxel))
    }

    /// The lobes of [`init_at`](Self::init_at) at point `p` of `node`, mapped from `voxel`
    /// (out of line: the learned directions, the default, need none of this).
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn init_lobes(
        &mut self,
        guide: &SkeletonGuide,
        scene: &Scene,
        p: Vec3,
        p_error: Vec3,
        normal: Vec3,
        wo: Vec3,
        (node, voxel): (u32, usize),
    ) -> u32 {
        let side = if normal.dot(wo) >= 0.0 {
            normal
        } else {
            -normal
        };
        let strength = guide.strength(node);
        let mut total = 0.0f32;
        // A node's lobes often share their bottleneck (every way out of a room leaves through
        // its door) or their importance point, and the answer depends on the target alone (p
        // is fixed; with visibility=voxel the voxel too): one shadow ray per distinct target.
        let mut aims = Aims {
            guide,
            scene,
            p,
            p_error,
            side,
            voxel,
            rays: 0,
            known: 0,
            found: 0,
            at: &mut self.aimed,
        };
        // Per portal slot of the node, the active lobe that samples it (u8::MAX: none yet).
        let mut portal_lobe = [u8::MAX; MAX_LOBES];
        let (lobes, plans) = guide.lobes_and_plans(node);
        for (j, (lobe, plan)) in lobes.iter().zip(plans).enumerate() {
            // lobe_weights=learned: a lobe the training gave 0 is never aimed (no shadow ray).
            if lobe.probability <= 0.0 {
                continue;
            }
            let slot = j;
            let j = j as u32;
            // One shadow ray toward the bottleneck decides whether p aims through it.
            let opening = if plan.through_opening {
                aims.aim(plan.opening_slot, lobe.opening, 2 * j)
            } else {
                None
            };
            // aim=portal: uniform toward the opening's rectangle where p sees the bottleneck
            // (and is not in the rectangle's plane); else the round lobe of aim=opening.
            if let (Some((axis, distance)), Some(portal_slot), Some(portal), LobeAim::Portal) =
                (opening, plan.portal_slot, &lobe.portal, guide.settings.aim)
            {
                // Lobes through the same rectangle are the same density at p (a portal lobe
                // has no strength): one active lobe with their summed probability, one
                // rectangle set-up and one density evaluation per direction instead of several.
                let i = portal_lobe[portal_slot as usize];
                if i != u8::MAX {
                    self.lobes[i as usize].probability += lobe.probability;
                    total += lobe.probability;
                    self.lobe_of[slot] = i;
                    continue;
                }
                let active = &mut self.lobes[self.count];
                if portal.seen_from_into(p, &mut active.rect) {
                    portal_lobe[portal_slot as usize] = self.count as u8;
                    self.lobe_of[slot] = self.count as u8;
                    active.axis = axis;
                    active.exponent = 0.0;
                    active.probability = lobe.probability;
                    active.radius = lobe.opening_radius;
                    active.distance = distance;
                    active.portal = true;
                    total += lobe.probability;
                    self.count += 1;
                    continue;
                }
            }
            // fallback=drop: a lobe whose opening p does not see applies nowhere else at p.
            let fall_back = !plan.through_opening || guide.settings.fallback == LobeFallback::Point;
            let target = match opening {
                Some((axis, distance)) => Some((axis, distance, lobe.opening_radius)),
                None if fall_back => aims
                    .aim(plan.point_slot, lobe.point, 2 * j + 1)
                    .map(|(axis, distance)| (axis, distance, lobe.radius)),
                None => None,
            };
            let Some((axis, distance, radius)) = target else {
                continue;
            };
            // A lobe toward the same target with the same radius is the same density under
            // any strength (the training pass's `pdf_with_strength` too): merged, as above.
            if let Some(i) = self.lobes[..self.count].iter().position(|l| {
                !l.portal && l.axis == axis && l.radius == radius && l.distance == distance
            }) {
                self.lobes[i].probability += lobe.probability;
                total += lobe.probability;
                self.lobe_of[slot] = i as u8;
                continue;
            }
            let active = &mut self.lobes[self.count];
            active.axis = axis;
            active.exponent = strength.exponent(radius, distance);
            active.probability = lobe.probability;
            active.radius = radius;
            active.distance = distance;
            active.portal = false;
            total += lobe.probability;
            self.lobe_of[slot] = self.count as u8;
            self.count += 1;
        }
        let rays = aims.rays;
        if total > 0.0 {
            for l in &mut self.lobes[..self.count] {
                l.probability /= total;
            }
            self.strength = Some(strength);
        } else {
            self.count = 0;
        }
        rays
    }

    /// The skeleton node of the last `init` (None outside the grid or in solid voxels, and
    /// where the point cannot map to a node with a guiding probability above 0: there the
    /// mapping is skipped).
    pub fn node(&self) -> Option<u32> {
        self.node
    }

    /// Lobes active at the current point.
    pub fn lobe_count(&self) -> usize {
        self.count
    }

    /// Axis, exponent and probability of active lobe `i`. A portal lobe (`aim=portal`,
    /// [`lobe_is_portal`](Self::lobe_is_portal)) samples a rectangle, not a power-cosine
    /// lobe: its exponent is meaningless (0).
    pub fn lobe(&self, i: usize) -> Option<(Vec3, f32, f32)> {
        (i < self.count).then(|| {
            let l = &self.lobes[i];
            (l.axis, l.exponent, l.probability)
        })
    }

    /// A hint after [`init`](Self::init): requests the cache line that sampling this point's
    /// learned distribution reads first (its row ends), so that the miss overlaps next-event
    /// estimation. No effect on any result.
    #[inline]
    pub fn prefetch_directions(&self) {
        if let Some(table) = self.learned() {
            table.prefetch(self.slot);
        }
    }

    /// The learned distribution that applies at this point (`directions=learned`), if any.
    #[inline]
    fn learned(&self) -> Option<&DirectionalTable> {
        if self.slot == NO_SLOT {
            return None;
        }
        self.directions.as_deref()
    }

    /// Whether active lobe `i` samples the opening's rectangle (`aim=portal`) at this point.
    pub fn lobe_is_portal(&self, i: usize) -> bool {
        i < self.count && self.lobes[i].portal
    }

    /// Lowers the guiding probability here to at most `c` (`ratio_max`): a bound the
    /// integrator derives from the path's prefix, before using any of the query's densities.
    #[inline]
    pub fn cap_guiding_probability(&mut self, c: f32) {
        if self.c_skel > c {
            self.c_skel = c.max(0.0);
        }
    }

    /// Probability of sampling the skeleton rather than the BSDF here: `c_skel` where lobes
    /// apply, else 0.
    pub fn guiding_probability(&self) -> f32 {
        if self.count > 0 || self.slot != NO_SLOT {
            self.c_skel
        } else {
            0.0
        }
    }

    /// Samples the skeleton mixture (eq. 167): `u_select` picks a lobe with its probability,
    /// `u` the direction in it. Returns the unit direction and the mixture's solid-angle pdf
    /// there (all lobes, as [`pdf`](Self::pdf)); `None` when not guided.
    pub fn sample(&self, u_select: f32, u: Vec2) -> Option<(Vec3, f32)> {
        if let Some(table) = self.learned() {
            let w = table.sample(self.slot, u_select, u);
            let pdf = table.pdf(self.slot, w);
            return (pdf > 0.0 && pdf.is_finite()).then_some((w, pdf));
        }
        if self.count == 0 {
            return None;
        }
        let (chosen, _) = pick_lobe(
            self.lobes[..self.count].iter().map(|l| l.probability),
            u_select,
        );
        let l = &self.lobes[chosen];
        let w = if l.portal {
            l.rect.sample(u)
        } else {
            Frame::from_z(l.axis).to_world(warp::power_cosine(u, l.exponent))
        };
        let pdf = self.pdf(w);
        (pdf > 0.0 && pdf.is_finite()).then_some((w, pdf))
    }

    /// Solid-angle pdf of the skeleton mixture (eq. 167) at unit direction `w`; 0 when not
    /// guided.
    pub fn pdf(&self, w: Vec3) -> f32 {
        if let Some(table) = self.learned() {
            return table.pdf(self.slot, w);
        }
        self.lobes[..self.count]
            .iter()
            .map(|l| l.probability * l.pdf(w, l.exponent))
            .sum()
    }

    /// [`pdf`](Self::pdf) as it would be with every lobe's exponent from `strength` instead
    /// (same lobes, axes and probabilities: which lobes apply at a point does not depend on
    /// the strength). Lobes of [`with_lobes`](Self::with_lobes) have no radius: an automatic
    /// strength gives them its bound. A portal lobe (`aim=portal`) has no strength: its
    /// density is the same under any.
    pub fn pdf_with_strength(&self, w: Vec3, strength: SkeletonStrength) -> f32 {
        // The lobes' own exponents are this strength's (`init`): the same sum, without
        // recomputing each exponent.
        if self.strength == Some(strength) {
            return self.pdf(w);
        }
        self.pdf_with_exponents_of(w, strength)
    }

    /// [`pdf_with_strength`](Self::pdf_with_strength) at a direction whose [`pdf`](Self::pdf)
    /// is known: the same value, without evaluating the density again under `init`'s strength.
    pub fn pdf_with_strength_given(&self, w: Vec3, strength: SkeletonStrength, pdf: f32) -> f32 {
        if self.strength == Some(strength) {
            return pdf;
        }
        self.pdf_with_exponents_of(w, strength)
    }

    /// [`pdf_with_strength`](Self::pdf_with_strength) with every exponent recomputed.
    fn pdf_with_exponents_of(&self, w: Vec3, strength: SkeletonStrength) -> f32 {
        self.lobes[..self.count]
            .iter()
            .map(|l| {
                let exponent = strength.exponent(l.radius, l.distance);
                l.probability * l.pdf(w, exponent)
            })
            .sum()
    }

    /// The density at unit direction `w` of each of the node's lobes (`SkeletonGuide::lobes`,
    /// in that order) as it applies at this point, or a negative number for a lobe that does
    /// not apply here; lobes merged into one active lobe get its density. With selection
    /// probabilities `W`, the mixture here is `sum W_j p_j / sum W_j` over the lobes that
    /// apply (the training's candidates, `guide::training`, "Lobe weights").
    pub fn node_lobe_pdfs(&self, w: Vec3) -> [f32; MAX_LOBES] {
        let mut active = [0.0f32; MAX_LOBES];
        for (p, l) in active.iter_mut().zip(&self.lobes[..self.count]) {
            *p = l.pdf(w, l.exponent);
        }
        self.lobe_of.map(|a| {
            if (a as usize) < self.count {
                active[a as usize]
            } else {
                -1.0
            }
        })
    }

    /// Density of the one-sample MIS combination with BSDF sampling (eq. 168-170), the
    /// estimator's denominator: `c p_skel(w) + (1 - c) p_bsdf(w)` with `c` the guiding
    /// probability. The thesis writes the balance-heuristic weights on projected solid angle
    /// (eq. 170 divides both densities by |cos|); the cosine cancels in f cos / (w p), so the
    /// estimator is f cos / this solid-angle mixture density.
    #[inline]
    pub fn mixture_pdf(&self, w: Vec3, bsdf_pdf: f32) -> f32 {
        let c = self.guiding_probability();
        if c > 0.0 {
            mix(c, self.pdf(w), bsdf_pdf)
        } else {
            bsdf_pdf
        }
    }

    /// [`mixture_pdf`](Self::mixture_pdf) at a direction whose skeleton density `guide_pdf`
    /// is known (what [`sample`](Self::sample) returned with it): the same value, without
    /// evaluating the density again.
    #[inline]
    pub fn mixture_pdf_given(&self, guide_pdf: f32, bsdf_pdf: f32) -> f32 {
        let c = self.guiding_probability();
        if c > 0.0 {
            mix(c, guide_pdf, bsdf_pdf)
        } else {
            bsdf_pdf
        }
    }
}

/// The one-sample mixture's density from its parts (eq. 168-170).
#[inline(always)]
fn mix(c: f32, guide_pdf: f32, bsdf_pdf: f32) -> f32 {
    c * guide_pdf + (1.0 - c) * bsdf_pdf
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Rng;

    #[test]
    fn query_with_lobes_validates_and_samples_its_pdf() {
        assert!(GuideQuery::with_lobes(1.0, &[(Vec3::Z, 2.0, 1.0)]).is_err());
        assert!(GuideQuery::with_lobes(0.5, &[(Vec3::ZERO, 2.0, 1.0)]).is_err());
        assert!(GuideQuery::with_lobes(0.5, &[(Vec3::Z, -2.0, 1.0)]).is_err());
        assert!(GuideQuery::with_lobes(0.5, &[(Vec3::Z, 2.0, 0.0)]).is_err());
        assert!(GuideQuery::with_lobes(0.5, &[(Vec3::Z, 2.0, 1.0); 9]).is_err());
        let empty = GuideQuery::new();
        assert_eq!(empty.guiding_probability(), 0.0);
        assert!(empty.sample(0.5, Vec2::splat(0.5)).is_none());
        assert_eq!(empty.mixture_pdf(Vec3::Z, 0.3), 0.3);
        let q = GuideQuery::with_lobes(
            0.25,
            &[(Vec3::Z, 10.0, 3.0), (Vec3::new(1.0, 0.0, 1.0), 1.0, 1.0)],
        )
        .unwrap();
        assert_eq!(q.lobe_count(), 2);
        assert!((q.lobe(0).unwrap().2 - 0.75).abs() < 1e-6);
        let mut rng = Rng::new(1, 2);
        for _ in 0..1000 {
            let (w, pdf) = q.sample(rng.uniform(), rng.uniform2()).unwrap();
            assert!((w.length() - 1.0).abs() < 1e-4);
            assert!((pdf - q.pdf(w)).abs() <= 1e-5 * pdf);
            let m = q.mixture_pdf(w, 0.1);
            assert!((m - (0.25 * pdf + 0.75 * 0.1)).abs() < 1e-5 * m);
        }
    }

    /// The training's shortcut: under the strength `init` set the lobes from,
    /// `pdf_with_strength` is `pdf`, bit for bit the sum with each exponent recomputed; under
    /// another strength it is that sum.
    #[test]
    fn pdf_with_the_query_strength_is_the_recomputed_sum() {
        use crate::guide::SkeletonGuideSettings;
        let scene = crate::scene::two_rooms_builder().unwrap().build().unwrap();
        let mut settings = SkeletonGuideSettings::default();
        // The lobes at a fixed c: no training.
        settings.set("c_skel", "0.5").unwrap();
        settings.set("directions", "lobes").unwrap();
        let guide = SkeletonGuide::build(&scene, scene.camera(), &settings, &|_, _| true).unwrap();
        let mut rng = Rng::new(9, 3);
        let bounds = scene.bounds();
        let mut query = GuideQuery::new();
        let (mut lobes, mut points) = (0, 0);
        while points < 2000 {
            let u = Vec3::new(rng.uniform(), rng.uniform(), rng.uniform());
            let o = bounds.min + (bounds.max - bounds.min) * u;
            let d = warp::uniform_sphere(rng.uniform2());
            let Some(si) = scene.intersect(&Ray::new(o, d, f32::INFINITY)) else {
                continue;
            };
            query.init(&guide, &scene, si.p, si.p_error, si.ng, si.wo);
            let Some(node) = query.node().filter(|_| query.lobe_count() > 0) else {
                continue;
            };
            points += 1;
            lobes += query.lobe_count();
            let strength = guide.strength(node);
            assert_eq!(query.strength, Some(strength));
            for _ in 0..4 {
                let w = warp::uniform_sphere(rng.uniform2());
                let full = query.pdf_with_exponents_of(w, strength);
                assert_eq!(
                    query.pdf_with_strength(w, strength).to_bits(),
                    full.to_bits()
                );
                assert_eq!(query.pdf(w).to_bits(), full.to_bits());
                let given = query.pdf_with_strength_given(w, strength, query.pdf(w));
                assert_eq!(given.to_bits(), full.to_bits());
                let other = SkeletonStrength::Fixed(3.0);
                assert_eq!(
                    query.pdf_with_strength(w, other).to_bits(),
                    query.pdf_with_exponents_of(w, other).to_bits()
                );
                assert_eq!(
                    query.pdf_with_strength_given(w, other, 1.0).to_bits(),
                    query.pdf_with_exponents_of(w, other).to_bits()
                );
            }
        }
        assert!(lobes > points, "{lobes} lobes at {points} points");
    }
}
