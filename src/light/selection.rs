//! Chooses one light per shading point with probability proportional to its power (alias
//! table, O(1)); lights with zero power are never chosen.

use super::Light;
use crate::math::AliasTable;

#[derive(Clone, Debug)]
pub struct LightSampler {
    table: AliasTable,
}

impl LightSampler {
    /// `None` when no light has positive power.
    pub fn new(lights: &[Light]) -> Option<Self> {
        Self::of_subset(lights, |_| true)
    }

    /// A sampler over the lights `member` accepts only (by power; the others never chosen);
    /// `None` when none of them has positive power.
    pub fn of_subset(lights: &[Light], member: impl Fn(usize) -> bool) -> Option<Self> {
        let powers: Vec<f32> = lights
            .iter()
            .enumerate()
            .map(|(i, l)| if member(i) { l.power().max(0.0) } else { 0.0 })
            .collect();
        // Non-finite powers (a light of huge radiance on a huge triangle) fall back to
        // uniform selection among the members rather than failing.
        if powers.iter().any(|p| !p.is_finite()) {
            let uniform: Vec<f32> = (0..lights.len())
                .map(|i| f32::from(u8::from(member(i))))
                .collect();
            return AliasTable::new(&uniform).map(|table| LightSampler { table });
        }
        AliasTable::new(&powers).map(|table| LightSampler { table })
    }

    /// The number of lights the sampler was built over (its table's length).
    pub fn len(&self) -> usize {
        self.table.len()
    }

    pub fn is_empty(&self) -> bool {
        self.table.is_empty()
    }

    /// Index of the chosen light and its probability.
    #[inline]
    pub fn sample(&self, u: f32) -> (usize, f32) {
        let i = self.table.sample(u);
        (i, self.table.pmf(i))
    }

    /// Index of the chosen light, its probability, and `u` rescaled to [0, 1) within the
    /// numbers that chose it ([`AliasTable::sample_reuse`]): the same choice and pmf as
    /// [`sample`](Self::sample), and next-event estimation passes the rescaled number on as
    /// one coordinate of the light's 2-D sample, so a stratified pair stays stratified over
    /// each light instead of only over the choice.
    #[inline]
    pub fn sample_reuse(&self, u: f32) -> (usize, f32, f32) {
        let (i, rescaled) = self.table.sample_reuse(u);
        (i, self.table.pmf(i), rescaled)
    }

    #[inline]
    pub fn pmf(&self, light: usize) -> f32 {
        self.table.pmf(light)
    }

    pub fn memory_bytes(&self) -> usize {
        self.table.memory_bytes()
    }
}
