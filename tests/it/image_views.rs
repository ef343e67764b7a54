//! The image as tools use it and views beyond the solve's own: RGBA images (alpha = 1 −
//! transmittance) over the sky or a transparent background, a partial `[camera]` completed from the
//! default view, and `lpm render` re-rendering a solved result from the data the solve keeps.

use crate::common::{lpm_command, temp_dir, write_scene, write_scene_as};
use lpm::job::SolveJob;
use lpm::render::Background;
use lpm::scene::{default_camera, fitted_default_camera, Projection, Scene};
use lpm::solver::BackendKind;
use std::path::{Path, PathBuf};

fn solve(scene: PathBuf, out: &Path, background: Background) {
    let job =
        SolveJob { backend: BackendKind::Cpu, no_fields: true, background, ..SolveJob::new(scene, out.to_path_buf()) };
    lpm::job::run(&job, |_, _| {}).expect("solve");
}

/// An EXR's size and RGBA pixels (row-major, top row first).
fn read_exr(path: &Path) -> (usize, usize, Vec<[f32; 4]>) {
    let image = exr::prelude::read_first_rgba_layer_from_file(
        path,
        |res, _| (res.width(), res.height(), vec![[0.0f32; 4]; res.width() * res.height()]),
        |img: &mut (usize, usize, Vec<[f32; 4]>), pos, (r, g, b, a): (f32, f32, f32, f32)| {
            let w = img.0;
            img.2[pos.y() * w + pos.x()] = [r, g, b, a];
        },
    )
    .expect("read exr");
    image.layer_data.channel_data.pixels
}

fn read_png(path: &Path) -> (png::ColorType, u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::fs::File::open(path).expect("open png"));
    let mut reader = decoder.read_info().expect("png header");
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).expect("png data");
    buf.truncate(info.buffer_size());
    (info.color_type, info.width, info.height, buf)
}

const SPHERE: &str = "[volume]\nprocedural = \"sphere\"\ndims = [16, 16, 16]\nvoxel_size = 1.0\n\
                      [medium]\nsigma_t = SIGMA\nalbedo = 0.8\n[[lights]]\nkind = \"sky\"\nradiance = 0.5\n\
                      [[lights]]\nkind = \"sun\"\ndirection = [0.3, 1.0, 0.2]\nirradiance = 2.0\n\
                      [solver]\ndirections_per_face = 2\nmax_orders = 4\n[camera]\nwidth = 48\nheight = 40\n";

/// Alpha is 0 exactly where a camera ray meets no medium (outside the volume, or through its
/// empty corners), and there the transparent image is black and the sky image the sky; a dense
/// sphere is opaque through its centre. The two images differ only by the background the
/// transmittance lets through, and the PNG carries alpha only for the transparent background.
#[test]
fn alpha_is_one_minus_transmittance_and_the_background_can_be_left_out() {
    let dir = temp_dir("image-alpha");
    let scene = write_scene(&dir, &SPHERE.replace("SIGMA", "40.0"));
    let (sky_out, clear_out) = (dir.join("sky"), dir.join("clear"));
    solve(scene.clone(), &sky_out, Background::Sky);
    solve(scene, &clear_out, Background::Transparent);
    let (w, h, sky) = read_exr(&sky_out.join("image.exr"));
    let (w2, h2, clear) = read_exr(&clear_out.join("image.exr"));
    assert_eq!((w, h), (48, 40));
    assert_eq!((w2, h2), (w, h));
    // The corner pixel misses the volume; the centre pixel crosses the sphere's dense middle.
    let (corner, centre) = (0, (h / 2) * w + w / 2);
    assert_eq!(sky[corner][3], 0.0);
    assert_eq!(clear[corner], [0.0; 4]);
    assert_eq!(sky[corner][..3], [0.5; 3]);
    assert!(clear[centre][3] > 1.0 - 1e-6, "a dense sphere is opaque: alpha {}", clear[centre][3]);
    assert!(clear[centre][0] > 0.0, "the lit medium shows");
    let mut empty = 0;
    for (s, c) in sky.iter().zip(&clear) {
        assert_eq!(s[3].to_bits(), c[3].to_bits(), "alpha does not depend on the background");
        for ch in 0..3 {
            // Grey medium: colour over the sky = colour over nothing + (1 − alpha)·sky.
            let want = c[ch] + (1.0 - c[3]) * 0.5;
            assert!((s[ch] - want).abs() <= 1e-6 * (1.0 + want.abs()), "{s:?} against {c:?}");
        }
        if c[3] == 0.0 {
            assert_eq!(c[..3], [0.0; 3], "a transparent pixel has no colour");
            empty += 1;
        }
    }
    assert!(empty > w * h / 10, "the view has empty pixels ({empty})");
    // PNG: opaque RGB over the sky, RGBA with straight alpha over nothing.
    let (ct, pw, ph, _) = read_png(&sky_out.join("image.png"));
    assert_eq!((ct, pw, ph), (png::ColorType::Rgb, 48, 40));
    let (ct, _, _, px) = read_png(&clear_out.join("image.png"));
    assert_eq!(ct, png::ColorType::Rgba);
    assert_eq!(px[..4], [0, 0, 0, 0]);
    assert_eq!(px[4 * centre + 3], 255);
}

/// A thin medium (σt small) lets most light through: alpha stays small but positive where the
/// rays cross the sphere.
#[test]
fn a_thin_medium_is_mostly_transparent() {
    let dir = temp_dir("image-thin");
    let scene = write_scene(&dir, &SPHERE.replace("SIGMA", "0.01"));
    let out = dir.join("out");
    solve(scene, &out, Background::Transparent);
    let (w, h, px) = read_exr(&out.join("image.exr"));
    let centre = px[(h / 2) * w + w / 2][3];
    assert!(centre > 0.0 && centre < 0.2, "alpha {centre}");
}

fn load(dir: &Path, camera: &str) -> Scene {
    let text = format!(
        "[volume]\nprocedural = \"sphere\"\ndims = [30, 20, 12]\nvoxel_size = 0.5\norigin = [3, 4, 5]\n\
         [medium]\nsigma_t = 1.0\nalbedo = 0.5\n{camera}"
    );
    Scene::load(&write_scene_as(dir, "partial.toml", &text)).unwrap_or_else(|e| panic!("{camera}: {e}"))
}

/// A `[camera]` with only some keys: without `position` and `look_at` it is the default view,
/// fitted to the size and field of view given (one size alone keeps the default aspect); a
/// hand-placed camera gets the volume's centre, the default eye, +z up and 512 pixels for what it
/// omits. The default view is the same whatever the volume's origin (it is in the volume's frame).
#[test]
fn a_partial_camera_takes_defaults_for_what_it_omits() {
    let dir = temp_dir("partial-camera");
    let (dims, h) = ([30, 20, 12], 0.5);
    let default = default_camera(dims, h);
    assert_eq!(load(&dir, "").camera, None);
    assert_eq!(load(&dir, "[camera]\n").camera, Some(default.clone()));
    let sized = load(&dir, "[camera]\nwidth = 64\nheight = 48\n").camera.unwrap();
    assert_eq!(sized, fitted_default_camera(dims, h, Some(64), Some(48), 40.0));
    assert_eq!((sized.width, sized.height), (64, 48));
    assert_eq!((sized.look_at, sized.up), (default.look_at, default.up));
    assert_ne!(sized.position, default.position, "the distance is fitted to the new aspect");
    let wide = load(&dir, "[camera]\nwidth = 1024\n").camera.unwrap();
    assert_eq!(wide.width, 1024);
    assert_eq!(wide, fitted_default_camera(dims, h, Some(1024), None, 40.0));
    let keep = 1024.0 * default.height as f64 / default.width as f64;
    assert!((wide.height as f64 - keep).abs() <= 2.5, "the aspect is kept: {} against {keep}", wide.height);
    assert!(
        (wide.position - default.position).length() < 0.01 * (default.position - default.look_at).length(),
        "about the same framing"
    );
    let tall = load(&dir, "[camera]\nheight = 300\n").camera.unwrap();
    assert_eq!(tall.height, 300);
    let narrow = load(&dir, "[camera]\nfov_y = 20\n").camera.unwrap();
    assert_eq!(narrow.projection, Projection::Pinhole { fov_y_degrees: 20.0 });
    assert!(
        (narrow.position - narrow.look_at).length() > (default.position - default.look_at).length(),
        "a narrower view stands further back"
    );
    let ortho = load(&dir, "[camera]\nprojection = \"orthographic\"\nwidth = 32\n").camera.unwrap();
    assert!(
        matches!(ortho.projection, Projection::Orthographic { height } if (height - 0.5 * (30f64 * 30.0 + 400.0 + 144.0).sqrt()).abs() < 1e-12)
    );
    // Hand-placed: look_at alone looks from the default eye at the given point (world frame).
    let look = load(&dir, "[camera]\nlook_at = [10, 8, 8]\n").camera.unwrap();
    assert!((look.position - default.position).length() < 1e-12, "the default eye");
    assert_eq!(look.look_at, glam::DVec3::new(7.0, 4.0, 3.0));
    assert_eq!((look.up, look.width, look.height), (glam::DVec3::Z, 512, 512));
    let eye = load(&dir, "[camera]\nposition = [3, 4, 30]\nup = [0, 1, 0]\n").camera.unwrap();
    assert_eq!(eye.look_at, glam::DVec3::new(7.5, 5.0, 3.0), "the volume's centre");
    assert_eq!(eye.position, glam::DVec3::new(0.0, 0.0, 25.0));
    // Still checked: a bad value names its key.
    let e = Scene::load(&write_scene_as(
        &dir,
        "bad.toml",
        "[volume]\nprocedural = \"sphere\"\ndims = [8, 8, 8]\n[medium]\nsigma_t = 1\nalbedo = 0.5\n[camera]\nwidth = 0\n",
    ))
    .unwrap_err();
    assert!(e.to_string().contains("camera.width"), "{e}");
}

fn lpm_ok(args: &[&str]) -> String {
    let o = lpm_command(args).output().expect("run lpm");
    assert!(o.status.success(), "lpm {args:?}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `lpm render OUT` from the solve's own view writes bitwise the solve's images; a new view (flags
/// or a camera file, omitted keys defaulted) gives a different image of the asked size, written
/// where asked, without solving again; a directory without render data is a clear error.
#[test]
fn lpm_render_re_renders_a_solved_result_from_a_new_view() {
    let dir = temp_dir("render-again");
    let scene = write_scene(
        &dir,
        &SPHERE
            .replace("SIGMA", "2.0")
            .replace("[camera]\nwidth = 48\nheight = 40\n", "")
            .replace("dims = [16, 16, 16]", "dims = [20, 16, 18]\norigin = [-2, 1, 0.5]"),
    );
    let out = dir.join("out");
    let out_s = out.to_str().unwrap();
    lpm_ok(&["solve", scene.to_str().unwrap(), "--out", out_s, "--backend", "cpu", "--no-fields"]);
    assert!(out.join("render-data/render.json").is_file());
    let solved_exr = std::fs::read(out.join("image.exr")).unwrap();
    let solved_png = std::fs::read(out.join("image.png")).unwrap();

    // The same view: the same bytes, into another file and over the solve's own images.
    let same = dir.join("same.exr");
    lpm_ok(&["render", out_s, "--image", same.to_str().unwrap()]);
    assert_eq!(std::fs::read(&same).unwrap(), solved_exr, "re-render of the solve's view");
    lpm_ok(&["render", out_s]);
    assert_eq!(std::fs::read(out.join("image.exr")).unwrap(), solved_exr);
    assert_eq!(std::fs::read(out.join("image.png")).unwrap(), solved_png);

    // A new view from flags: a width alone keeps the aspect ratio.
    let (w0, h0, solved) = read_exr(&same);
    let moved = dir.join("moved.exr");
    lpm_ok(&[
        "render",
        out_s,
        "--eye",
        "-30,20,-25",
        "--target",
        "8,9,9.5",
        "--width",
        "64",
        "--image",
        moved.to_str().unwrap(),
    ]);
    let (w, h, px) = read_exr(&moved);
    assert_eq!((w, h), (64, (64.0 * h0 as f64 / w0 as f64).round() as usize));
    assert!(px.iter().any(|p| p[3] > 0.5), "the new view sees the sphere");
    assert_ne!(px.len(), solved.len());

    // A camera file ([camera] keys, completed as a scene's), and a transparent PNG.
    let cam = dir.join("cam.toml");
    std::fs::write(&cam, "[camera]\nwidth = 40\nheight = 30\nfov_y = 30\n").unwrap();
    let png_path = dir.join("view.png");
    lpm_ok(&[
        "render",
        out_s,
        "--camera",
        cam.to_str().unwrap(),
        "--background",
        "transparent",
        "--image",
        png_path.to_str().unwrap(),
    ]);
    let (ct, pw, ph, _) = read_png(&png_path);
    assert_eq!((ct, pw, ph), (png::ColorType::Rgba, 40, 30));
    // The solve's images are untouched by renders to other files.
    assert_eq!(std::fs::read(out.join("image.exr")).unwrap(), solved_exr);

    // No render data: a clear error, nothing written.
    std::fs::remove_dir_all(out.join("render-data")).unwrap();
    let o = lpm_command(&["render", out_s, "--image", dir.join("none.exr").to_str().unwrap()]).output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("render-data") && err.contains("--no-render-data"), "{err}");
    assert!(!dir.join("none.exr").exists());
    let o = lpm_command(&["render", out_s, "--image", dir.join("x.jpg").to_str().unwrap()]).output().unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains(".exr or .png"));
}

/// The PNG's exposure and view transform: `[camera]`'s `exposure` and `view` keys (checked, with
/// the key named), overridden by `--exposure`/`--view` on the solve, kept in render-data so that
/// `lpm render OUT` writes the solve's PNG bitwise, and changed there by the same flags; the PNG is
/// exactly the EXR through `render::tone` at 2^EV. On a sunlit sphere the default (AgX) spreads the
/// lit and shaded sides over more of the 8-bit range than the old mapping (`standard`).
#[test]
fn exposure_and_view_from_the_camera_keys_and_the_flags() {
    use lpm::render::tone::pixel_u8;
    use lpm::scene::{Exposure, View};
    let dir = temp_dir("render-display");
    // The keys are checked, naming the key.
    for (keys, key, words) in [
        ("view = \"aces\"", "camera.view", "\"standard\", \"filmic\", \"agx\""),
        ("exposure = 40", "camera.exposure", "[-32, 32]"),
        ("exposure = \"bright\"", "camera.exposure", "\"auto\""),
        ("exposure = nan", "camera.exposure", "finite"),
    ] {
        let text = SPHERE.replace("SIGMA", "2.0") + keys + "\n";
        let e = Scene::from_toml_str(&text, &dir.join("keys.toml")).unwrap_err().to_string();
        assert!(e.contains(key) && e.contains(words), "{keys}: {e}");
    }
    let text = SPHERE.replace("SIGMA", "2.0") + "exposure = -1.5\nview = \"filmic\"\n";
    let scene = Scene::from_toml_str(&text, &dir.join("keys.toml")).unwrap();
    assert_eq!((scene.display.view, scene.display.exposure), (View::Filmic, Exposure::Ev(-1.5)));
    let plain = Scene::from_toml_str(&SPHERE.replace("SIGMA", "2.0"), &dir.join("keys.toml")).unwrap();
    assert_eq!((plain.display.view, plain.display.exposure), (View::Agx, Exposure::Ev(0.0)), "the defaults");

    // A solve with the keys: its PNG is its EXR at 2^1 through filmic.
    let scene = write_scene(&dir, &(SPHERE.replace("SIGMA", "2.0") + "exposure = 1\nview = \"filmic\"\n"));
    let out = dir.join("out");
    let out_s = out.to_str().unwrap();
    lpm_ok(&["solve", scene.to_str().unwrap(), "--out", out_s, "--backend", "cpu", "--no-fields"]);
    let (_, _, exr) = read_exr(&out.join("image.exr"));
    let as_png = |scale: f64, view: View| -> Vec<u8> {
        exr.iter().flat_map(|p| pixel_u8([p[0], p[1], p[2]], scale, view)).collect::<Vec<u8>>()
    };
    let (_, _, _, png) = read_png(&out.join("image.png"));
    assert_eq!(png, as_png(2.0, View::Filmic), "the PNG is the EXR through the scene's exposure and view");
    let kept: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("render-data/render.json")).unwrap()).unwrap();
    assert_eq!(kept["display"], serde_json::json!({"view": "filmic", "exposure": 1.0}));

    // `lpm render OUT` keeps the solve's mapping (bitwise), the flags change it.
    let solved_png = std::fs::read(out.join("image.png")).unwrap();
    lpm_ok(&["render", out_s]);
    assert_eq!(std::fs::read(out.join("image.png")).unwrap(), solved_png, "re-render with the solve's mapping");
    let std_png = dir.join("standard.png");
    lpm_ok(&["render", out_s, "--view", "standard", "--exposure", "-1", "--image", std_png.to_str().unwrap()]);
    assert_eq!(read_png(&std_png).3, as_png(0.5, View::Standard));
    let auto_png = dir.join("auto.png");
    lpm_ok(&["render", out_s, "--exposure", "auto", "--image", auto_png.to_str().unwrap()]);
    assert_ne!(read_png(&auto_png).3, png, "auto exposure changes the PNG");
    for (flag, value, words) in
        [("--exposure", "99", "[-32, 32]"), ("--exposure", "loud", "\"auto\""), ("--view", "aces", "agx")]
    {
        let o = lpm_command(&["render", out_s, flag, value]).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(flag) && err.contains(words), "{flag} {value}: {err}");
    }

    // The solve's flags override the keys, and are what render-data keeps.
    let out2 = dir.join("out2");
    lpm_ok(&[
        "solve",
        scene.to_str().unwrap(),
        "--out",
        out2.to_str().unwrap(),
        "--backend",
        "cpu",
        "--no-fields",
        "--view",
        "agx",
        "--exposure",
        "auto",
    ]);
    let kept: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out2.join("render-data/render.json")).unwrap()).unwrap();
    assert_eq!(kept["display"], serde_json::json!({"view": "agx", "exposure": "auto"}));

    // Lit and shaded sides: over the pixels that see the sphere, the default view at EV 0 spans
    // more 8-bit levels than the old mapping did.
    let spread = |view: View| {
        let greens: Vec<u8> =
            exr.iter().filter(|p| p[3] > 0.9).map(|p| pixel_u8([p[0], p[1], p[2]], 1.0, view)[1]).collect();
        greens.iter().max().unwrap() - greens.iter().min().unwrap()
    };
    assert!(
        spread(View::Agx) > spread(View::Standard),
        "agx {} vs standard {}",
        spread(View::Agx),
        spread(View::Standard)
    );
}
