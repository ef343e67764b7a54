//! Property (issue 13): any scene the validator accepts — here small ones drawn over the whole
//! accepted range of every light and medium value, extremes included — solves on the CPU twin to
//! finite, non-negative fluence and source. Together with the validator's bounds
//! (`scene::validate::MAX_LIGHT`), this is what makes "finite in, finite out" hold.
use lpm::scene::Scene;
use lpm::solver::BackendKind;
use proptest::prelude::*;
use std::path::Path;

/// A value in [0, max] with the ends and a spread of magnitudes well represented.
fn magnitude(max: f64) -> impl Strategy<Value = f64> {
    prop_oneof![Just(0.0), Just(max), (-12.0f64..max.log10()).prop_map(move |e| 10f64.powf(e).min(max))]
}

fn vec3() -> impl Strategy<Value = [f64; 3]> {
    prop_oneof![
        prop::array::uniform3(-1.0f64..1.0),
        prop::array::uniform3(prop_oneof![Just(1e300), Just(-1e300), Just(1e-300), Just(0.0), -5.0f64..5.0]),
    ]
}

prop_compose! {
    fn scene_text()(
        dims in prop::array::uniform3(1u32..20),
        shape in prop::sample::select(vec!["sphere", "box", "cloud"]),
        sigma_t in prop::array::uniform3(magnitude(1e3)),
        albedo in prop::array::uniform3(prop_oneof![Just(0.0), Just(1.0), 0.0f64..1.0]),
        g in -0.95f64..0.95,
        emission in magnitude(lpm::scene::validate::MAX_LIGHT),
        sky in magnitude(lpm::scene::validate::MAX_LIGHT),
        sun in vec3(),
        irradiance in magnitude(lpm::scene::validate::MAX_LIGHT),
        k in 1u32..3,
    ) -> String {
        format!(
            "[volume]\nprocedural = \"{shape}\"\ndims = {dims:?}\n\
             [medium]\nsigma_t = {sigma_t:?}\nalbedo = {albedo:?}\ng = {g:?}\nemission = {emission:?}\n\
             [[lights]]\nkind = \"sky\"\nradiance = {sky:?}\n\
             [[lights]]\nkind = \"sun\"\ndirection = {sun:?}\nirradiance = {irradiance:?}\n\
             [solver]\ndirections_per_face = {k}\nmax_orders = 4\n"
        )
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn accepted_scenes_solve_to_finite_non_negative_fields(text in scene_text()) {
        let Ok(scene) = Scene::from_toml_str(&text, Path::new("prop.toml")) else {
            // Refused with a typed error (say the zero sun direction): nothing to solve.
            return Ok(());
        };
        let s = crate::common::solve("prop-solve", &scene, BackendKind::Cpu);
        for (name, field) in [("fluence", &s.fields.fluence_total), ("source", &s.fields.source_total)] {
            let bad = field.as_slice().iter().position(|v| !(v.is_finite() && *v >= 0.0));
            prop_assert!(bad.is_none(), "{name}[{:?}] = {:?} for\n{text}", bad, bad.map(|i| field.as_slice()[i]));
        }
    }
}
