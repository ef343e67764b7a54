//! The camera ray-march against closed-form answers, and the image files.

use glam::DVec3;
use lpm::quadrature::Blend;
use lpm::render::{default_camera, render, write_exr, write_png, Image, RenderInputs};
use lpm::scene::{Camera, Display, Medium, Projection};
use lpm::store::{BrickStore, Coverage, Field, BRICK_VOXELS};
use std::fs;
use std::path::{Path, PathBuf};

struct TestDir(PathBuf);

impl std::ops::Deref for TestDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TestDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

fn test_dir(name: &str) -> TestDir {
    let dir = std::env::temp_dir().join(format!("lpm-render-test-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).expect("create test dir");
    TestDir(dir)
}

/// A store of `dims` voxels of size `h`, density 1 everywhere (or 0 when `empty`).
fn uniform_store(dir: &Path, dims: [u32; 3], h: f64, density: f32) -> BrickStore {
    BrickStore::create_with(dir, dims, h, |_, out| {
        out.fill(density);
        Ok(())
    })
    .expect("create store")
}

fn medium(sigma_t: [f64; 3], albedo: f64, emission: f64) -> Medium {
    Medium { sigma_t, albedo: [albedo; 3], g: 0.0, emission: [emission; 3] }
}

/// An orthographic camera looking along `dir` through the point `target`, 3×3 pixels, so the centre
/// pixel's ray passes exactly through `target`.
fn ortho_through(target: DVec3, dir: DVec3) -> Camera {
    let dir = dir.normalize();
    let up = if dir.y.abs() < 0.9 { DVec3::Y } else { DVec3::X };
    Camera {
        projection: Projection::Orthographic { height: 1.0 },
        position: target - dir * 50.0,
        look_at: target,
        up,
        width: 3,
        height: 3,
    }
}

/// Length of the chord of the box `[0, size]` along `dir` through its centre.
fn chord_through_centre(size: DVec3, dir: DVec3) -> f64 {
    let d = dir.normalize().abs();
    2.0 * (0..3).filter(|&a| d[a] > 0.0).map(|a| 0.5 * size[a] / d[a]).fold(f64::INFINITY, f64::min)
}

// Positional on purpose: every test spells out the whole render input in one line.
#[allow(clippy::too_many_arguments)]
fn inputs<'a>(
    store: &'a BrickStore,
    source: &'a Field,
    channels: u32,
    storage_dirs: u32,
    lookup: &'a (dyn Fn(DVec3) -> Blend + Sync),
    medium: &'a Medium,
    background: [f64; 3],
    camera: &'a Camera,
) -> RenderInputs<'a> {
    RenderInputs {
        store,
        source,
        emission: None,
        albedo: None,
        channels,
        storage_dirs,
        storage_lookup: lookup,
        medium,
        single: None,
        background,
        environment: None,
        camera,
    }
}

#[test]
fn empty_volume_renders_exactly_the_background() {
    let dir = test_dir("empty");
    let store = uniform_store(&dir, [20, 9, 33], 0.1, 0.0);
    let source = store.create_field("source", 1, Coverage::Occupied).expect("field");
    let m = medium([3.0; 3], 0.5, 1.0);
    let bg = [0.3, 0.5, 0.7];
    let camera = default_camera(store.grid().dims, store.voxel_size());
    assert_eq!(camera.width, 512);
    let lookup = |_: DVec3| Blend::single(0);
    let img = render(&inputs(&store, &source, 1, 1, &lookup, &m, bg, &camera));
    assert_eq!((img.width, img.height), (camera.width, camera.height));
    let expected = bg.map(|v| v as f32);
    assert!(img.rgb.chunks(3).all(|p| p == expected));
}

#[test]
fn pure_absorber_follows_beer_lambert() {
    let dir = test_dir("absorber");
    let (dims, h) = ([20u32, 17, 24], 0.25);
    let store = uniform_store(&dir, dims, h, 1.0);
    let source = store.create_field("source", 1, Coverage::Occupied).expect("field");
    let sigma_t = [0.5, 1.0, 2.0];
    let m = medium(sigma_t, 0.0, 0.0);
    let bg = [1.0, 2.0, 3.0];
    let size = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * h;
    let lookup = |_: DVec3| Blend::single(0);
    for dir_ in [DVec3::Z, DVec3::NEG_X, DVec3::new(1.0, 0.7, 0.4), DVec3::new(-0.3, -1.0, 0.55)] {
        let camera = ortho_through(size * 0.5, dir_);
        let img = render(&inputs(&store, &source, 1, 1, &lookup, &m, bg, &camera));
        let length = chord_through_centre(size, dir_);
        let centre = img.pixel(1, 1);
        for ch in 0..3 {
            let expected = bg[ch] * (-sigma_t[ch] * length).exp();
            let err = (centre[ch] as f64 - expected).abs();
            assert!(err <= 1e-5 * expected.max(1e-3), "dir {dir_} channel {ch}: {} vs {expected}", centre[ch]);
        }
    }
}

#[test]
fn uniform_source_without_extinction_integrates_the_path_length() {
    let dir = test_dir("source");
    let (dims, h) = ([18u32, 20, 21], 0.5);
    let store = uniform_store(&dir, dims, h, 1.0);
    // Two storage directions, three channels: the camera looking along +z sees light travelling
    // along −z, which this lookup stores in direction 1.
    let (channels, dirs) = (3u32, 2u32);
    let q = [[10.0f32, 20.0, 30.0], [1.0, 2.0, 3.0]];
    let mut source = store.create_field("source", dirs * channels, Coverage::Occupied).expect("field");
    for b in store.occupied_bricks().collect::<Vec<_>>() {
        let data = source.brick_mut(b).expect("occupied");
        for (d, qd) in q.iter().enumerate() {
            for (ch, &value) in qd.iter().enumerate() {
                let c = d * channels as usize + ch;
                data[c * BRICK_VOXELS..(c + 1) * BRICK_VOXELS].fill(value);
            }
        }
    }
    let m = medium([0.0; 3], 0.5, 0.0);
    let lookup = |travel: DVec3| Blend::single(if travel.z > 0.0 { 0 } else { 1 });
    let size = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * h;
    let camera = ortho_through(size * 0.5, DVec3::Z);
    let img = render(&inputs(&store, &source, channels, dirs, &lookup, &m, [0.0; 3], &camera));
    let length = size.z;
    for (ch, &qc) in q[1].iter().enumerate() {
        let expected = qc as f64 * length;
        assert!((img.pixel(1, 1)[ch] as f64 - expected).abs() <= 1e-5 * expected, "{:?}", img.pixel(1, 1));
    }
    // Looking the other way picks the other storage direction; read as grey (1 channel, so component
    // = direction), direction 0 is component 0 = q[0][0], used for r, g and b.
    let camera = ortho_through(size * 0.5, DVec3::NEG_Z);
    let img = render(&inputs(&store, &source, 1, dirs * 3, &lookup, &m, [0.0; 3], &camera));
    let expected = q[0][0] as f64 * length;
    for ch in 0..3 {
        assert!((img.pixel(1, 1)[ch] as f64 - expected).abs() <= 1e-5 * expected);
    }
}

#[test]
fn emission_saturates_at_le() {
    let dir = test_dir("emission");
    let (dims, h) = ([16u32, 16, 16], 0.25);
    let store = uniform_store(&dir, dims, h, 1.0);
    let source = store.create_field("source", 1, Coverage::Occupied).expect("field");
    let m = medium([1.0, 2.0, 4.0], 0.0, 2.0);
    let size = DVec3::splat(4.0);
    let lookup = |_: DVec3| Blend::single(0);
    let camera = ortho_through(size * 0.5, DVec3::X);
    let img = render(&inputs(&store, &source, 1, 1, &lookup, &m, [0.0; 3], &camera));
    for ch in 0..3 {
        let expected = 2.0 * -(-m.sigma_t[ch] * 4.0f64).exp_m1();
        assert!((img.pixel(1, 1)[ch] as f64 - expected).abs() <= 1e-5 * expected);
    }
}

#[test]
fn default_camera_frames_the_whole_volume_and_render_is_deterministic() {
    let dir = test_dir("default");
    let dims = [40u32, 10, 25];
    let store = uniform_store(&dir, dims, 0.1, 1.0);
    let source = store.create_field("source", 1, Coverage::Occupied).expect("field");
    let m = medium([5.0; 3], 0.0, 0.0);
    // The default view, at a smaller size with the same aspect (keeps the test fast).
    let full = default_camera(dims, 0.1);
    let camera = Camera { width: 96, height: (96 * full.height).div_ceil(full.width).max(1), ..full };
    let lookup = |_: DVec3| Blend::single(0);
    let bg = [1.0; 3];
    let img = render(&inputs(&store, &source, 1, 1, &lookup, &m, bg, &camera));
    let (w, h) = (img.width, img.height);
    // The border shows only background: the volume is entirely inside the frame.
    for x in 0..w {
        assert_eq!(img.pixel(x, 0), [1.0; 3]);
        assert_eq!(img.pixel(x, h - 1), [1.0; 3]);
    }
    for y in 0..h {
        assert_eq!(img.pixel(0, y), [1.0; 3]);
        assert_eq!(img.pixel(w - 1, y), [1.0; 3]);
    }
    assert!(img.pixel(w / 2, h / 2)[0] < 0.5, "the volume is in the middle");
    let again = render(&inputs(&store, &source, 1, 1, &lookup, &m, bg, &camera));
    assert_eq!(img, again);
}

#[test]
fn exr_and_png_are_written_atomically_and_read_back() {
    let dir = test_dir("files");
    let (w, h) = (7u32, 5u32);
    // Pixel 0 black in all three channels (AgX mixes the channels: a black red beside a lit green is not black).
    let rgb: Vec<f32> = (0..w * h * 3).map(|i| if i < 3 { 0.0 } else { i as f32 * 0.125 }).collect();
    let img = Image { width: w, height: h, rgb, alpha: None };

    let exr_path = dir.join("view.exr");
    write_exr(&exr_path, &img).expect("exr");
    let read = exr::prelude::read_first_rgba_layer_from_file(
        &exr_path,
        |res, _| (res.width(), vec![0.0f32; res.width() * res.height() * 3]),
        |(width, px): &mut (usize, Vec<f32>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            let i = 3 * (pos.y() * *width + pos.x());
            px[i..i + 3].copy_from_slice(&[r, g, b]);
        },
    )
    .expect("read exr");
    let layer = &read.layer_data;
    assert_eq!((layer.size.width(), layer.size.height()), (w as usize, h as usize));
    assert_eq!(layer.channel_data.pixels.1, img.rgb);

    let png_path = dir.join("view.png");
    write_png(&png_path, &img, &Display::default()).expect("png");
    let decoder = png::Decoder::new(fs::File::open(&png_path).expect("open png"));
    let mut reader = decoder.read_info().expect("png header");
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buf).expect("png data");
    assert_eq!((frame.width, frame.height), (w, h));
    assert_eq!(frame.color_type, png::ColorType::Rgb);
    assert_eq!(buf[0], 0, "zero radiance is black");
    assert!(buf[frame.buffer_size() - 1] > 200, "bright pixels are near white");

    // Only the two finished files remain: no temporaries.
    let mut names: Vec<_> = fs::read_dir(&*dir).expect("dir").map(|e| e.expect("entry").file_name()).collect();
    names.sort();
    assert_eq!(names, vec!["view.exr", "view.png"]);

    // A malformed image is refused and writes nothing.
    let bad = Image { width: 3, height: 3, rgb: vec![0.0; 5], alpha: None };
    assert!(write_exr(&dir.join("bad.exr"), &bad).is_err());
    assert!(write_png(&dir.join("bad.png"), &bad, &Display::default()).is_err());
    assert!(!dir.join("bad.exr").exists() && !dir.join("bad.png").exists());
}
