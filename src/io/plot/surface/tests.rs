use std::path::{Path, PathBuf};

use super::*;
use crate::io::plot::axes::BACKGROUND;
use crate::io::plot::colormap::lightness;
use crate::io::test_support::TempDir;

// ---------------------------------------------------------------- helpers

/// A unit sphere ([`crate::testing::icosphere`], 20·4^level triangles, counter-clockwise seen
/// from outside).
fn icosphere(level: usize) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    crate::testing::icosphere(1.0, level)
}

/// A closed tetrahedron of edge ~`size` around `c`, outward.
fn tetra(c: [f64; 3], size: f64) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let s = size / 2.0;
    let v = vec![
        [c[0] + s, c[1] + s, c[2] + s],
        [c[0] + s, c[1] - s, c[2] - s],
        [c[0] - s, c[1] + s, c[2] - s],
        [c[0] - s, c[1] - s, c[2] + s],
    ];
    (v, vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
}

/// A rectangle in the plane x = `x`, y in `y`, z in `z`, as two triangles
/// facing +x.
fn quad_x(x: f64, y: (f64, f64), z: (f64, f64)) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let v = vec![[x, y.0, z.0], [x, y.1, z.0], [x, y.1, z.1], [x, y.0, z.1]];
    (v, vec![[0, 1, 2], [0, 2, 3]])
}

/// A surface: its vertices and triangles.
type Mesh = (Vec<[f64; 3]>, Vec<[usize; 3]>);

/// Merges surfaces into one vertex and triangle list.
fn merge(parts: &[Mesh]) -> Mesh {
    let (mut v, mut f) = (Vec::new(), Vec::new());
    for (pv, pf) in parts {
        let off = v.len();
        v.extend_from_slice(pv);
        f.extend(pf.iter().map(|t| t.map(|i| i + off)));
    }
    (v, f)
}

fn figure(panels: Vec<SurfacePanel>, views: Vec<View>, size: u32) -> SurfaceFigure {
    let mut fig = SurfaceFigure::new("", panels);
    fig.views = views;
    fig.panel_size = size;
    fig
}

/// Pixels of `rect` that are not background, with their colours.
fn covered(c: &Canvas, rect: PixelRect) -> Vec<(i32, i32, Rgb)> {
    let mut out = Vec::new();
    for y in rect.y0..rect.y1 {
        for x in rect.x0..rect.x1 {
            let p = c.pixel(x as u32, y as u32);
            if p != BACKGROUND {
                out.push((x, y, p));
            }
        }
    }
    out
}

/// The colour of the pixel under world point `p` in a cell.
fn colour_at(c: &Canvas, cam: &Camera, p: [f64; 3]) -> Rgb {
    let s = cam.project(p);
    c.pixel(s[0].floor() as u32, s[1].floor() as u32)
}

fn no_path() -> PathBuf {
    PathBuf::from("unused.png")
}

// ------------------------------------------------------------------ tests

#[test]
fn a_facing_triangle_covers_its_projected_area() {
    let v = vec![[0.0, -1.0, -1.0], [0.0, 1.0, -0.6], [0.0, -0.2, 1.0]];
    // A marker far off the body projects outside the cell: left out.
    let panel = SurfacePanel::new("", v.clone(), vec![[0, 1, 2]]).with_marker(SurfaceMarker::new(
        [0.0, 50.0, 0.0],
        "far",
        [255, 0, 0],
    ));
    // Viewed from +x (azimuth 0, elevation 0) the triangle faces the eye.
    let fig = figure(vec![panel], vec![View::labelled(0.0, 0.0, "")], 200);
    let (c, layout) = render_surface(&no_path(), &fig).unwrap();
    let (rect, cam) = layout.cells[0][0];
    assert_eq!(layout.marker_visible[0][0], vec![false]);
    // Shared scale: the bounding sphere's diameter spans FILL of the cell.
    let (centre, r) = bounding_sphere(&v);
    assert!((layout.scale - FILL * 100.0 / r).abs() < 1e-12);
    assert_eq!(cam.centre, centre);

    let area = 0.5 * norm(cross(sub(v[1], v[0]), sub(v[2], v[0]))) * layout.scale.powi(2);
    let perimeter: f64 =
        (0..3).map(|k| norm(sub(v[(k + 1) % 3], v[k]))).sum::<f64>() * layout.scale;
    let px = covered(&c, rect);
    let n = px.len() as f64;
    // Centre sampling misses or adds at most the pixels the edges cross.
    assert!(
        (n - area).abs() < 0.5 * perimeter,
        "{n} pixels for a projected area of {area:.1} (perimeter {perimeter:.1} px)"
    );
    // Flat and facing the eye: one colour, plain grey times the Lambert shade.
    let expected = shaded(PLAIN, shade([1.0, 0.0, 0.0], cam.light()));
    assert!(
        px.iter().all(|p| p.2 == expected),
        "{:?} vs {expected:?}",
        px[0]
    );
    // The corners land where the camera says (probe just inside each).
    let g: [f64; 3] = [0, 1, 2].map(|k| (v[0][k] + v[1][k] + v[2][k]) / 3.0);
    for corner in &v {
        let inside = [0, 1, 2].map(|k| corner[k] + 0.05 * (g[k] - corner[k]));
        assert_eq!(colour_at(&c, &cam, inside), expected);
        let outside = [0, 1, 2].map(|k| corner[k] - 0.05 * (g[k] - corner[k]));
        assert_eq!(colour_at(&c, &cam, outside), BACKGROUND);
    }
}

#[test]
fn nearer_surfaces_hide_farther_ones_in_any_order() {
    // Near square (x = 0.5, value 1) and far square (x = 0, value 0),
    // overlapping for y in [-0.5, 0.5].
    let near = quad_x(0.5, (-1.0, 0.5), (-1.0, 1.0));
    let far = quad_x(0.0, (-0.5, 1.0), (-1.0, 1.0));
    let values_nf = vec![1.0; 4]
        .into_iter()
        .chain(vec![0.0; 4])
        .collect::<Vec<_>>();
    let values_fn = vec![0.0; 4]
        .into_iter()
        .chain(vec![1.0; 4])
        .collect::<Vec<_>>();
    let (v1, f1) = merge(&[near.clone(), far.clone()]);
    let (v2, f2) = merge(&[far, near]);
    let panels = vec![
        SurfacePanel::new("near first", v1, f1).with_values(values_nf),
        SurfacePanel::new("far first", v2, f2).with_values(values_fn),
    ];
    let fig = figure(
        panels,
        vec![View::new(0.0, 0.0), View::new(180.0, 0.0)],
        120,
    );
    let (c, layout) = render_surface(&no_path(), &fig).unwrap();
    let yellow = |p: Rgb| p[1] > 100; // colormap(1) = [255, 244, 101], shaded ≥ 0.42
    let violet = |p: Rgb| p != BACKGROUND && p[1] < 20; // colormap(0) = [46, 10, 74]
    for k in 0..2 {
        // From +x the near (yellow) square wins the overlap.
        let (_, cam) = layout.cells[0][k];
        let at = |y: f64| colour_at(&c, &cam, [0.25, y, 0.1]);
        assert!(yellow(at(0.0)), "panel {k}: overlap shows {:?}", at(0.0));
        assert!(yellow(at(-0.8)) && violet(at(0.8)), "panel {k}");
        // From -x the roles swap.
        let (_, cam) = layout.cells[1][k];
        let at = |y: f64| colour_at(&c, &cam, [0.25, y, 0.1]);
        assert!(violet(at(0.0)), "panel {k} from behind: {:?}", at(0.0));
        assert!(yellow(at(-0.8)) && violet(at(0.8)), "panel {k} from behind");
    }
}

#[test]
fn a_ramp_is_coloured_monotonically_and_holes_are_grey() {
    // Values = y across a quad facing +x; a second quad has NaN on its
    // right-hand corners.
    let (v, f) = quad_x(0.0, (-1.0, 1.0), (-0.5, 0.5));
    let ramp: Vec<f64> = v.iter().map(|p| p[1]).collect();
    let holed = vec![0.0, f64::NAN, f64::NAN, 0.0];
    let panels = vec![
        SurfacePanel::new("", v.clone(), f.clone()).with_values(ramp),
        SurfacePanel::new("", v, f).with_values(holed),
    ];
    let fig = figure(panels, vec![View::new(0.0, 0.0)], 160);
    let (c, layout) = render_surface(&no_path(), &fig).unwrap();
    // Default range: the finite values of all panels, -1 .. 1.
    let (_, map) = layout.colorbar.unwrap();
    assert_eq!((map.lo, map.hi), (-1.0, 1.0));

    let (rect, cam) = layout.cells[0][0];
    let s = shade([1.0, 0.0, 0.0], cam.light());
    let row = cam.project([0.0, 0.0, 0.0])[1].floor() as i32;
    let (x0, x1) = (
        cam.project([0.0, -1.0, 0.0])[0].ceil() as i32,
        cam.project([0.0, 1.0, 0.0])[0].floor() as i32,
    );
    let mut lstar = Vec::new();
    for x in x0..x1 {
        // World y of this pixel centre (right = +y from azimuth 0).
        let y = (x as f64 + 0.5 - cam.origin.0) / cam.scale + cam.centre[1];
        let expected = shaded(colormap((y + 1.0) / 2.0), s);
        let got = c.pixel(x as u32, row as u32);
        assert!(
            (0..3).all(|k| (got[k] as i32 - expected[k] as i32).abs() <= 1),
            "x {x} (y {y:.3}): {got:?} vs {expected:?}"
        );
        lstar.push(lightness(got));
    }
    assert!(lstar.len() > 100, "{} pixels across", lstar.len());
    for w in lstar.windows(2) {
        assert!(w[1] >= w[0] - 0.3, "lightness falls along the ramp: {w:?}");
    }
    assert!(lstar[lstar.len() - 1] - lstar[0] > 50.0, "{lstar:?}");
    assert!(rect.contains(x0, row) && rect.contains(x1, row));

    // The holed quad: the finite side has the colour of 0, the NaN side grey.
    let (_, cam) = layout.cells[0][1];
    let mid = shaded(colormap(0.5), s);
    assert_eq!(colour_at(&c, &cam, [0.0, -0.9, 0.0]), mid);
    assert_eq!(colour_at(&c, &cam, [0.0, 0.9, 0.0]), shaded(PLAIN, s));
}

#[test]
fn views_put_things_where_the_angles_say() {
    // Yellow tetrahedron at +y, violet one at -x; z is up.
    let (v, f) = merge(&[tetra([0.0, 1.0, 0.0], 0.6), tetra([-1.0, 0.0, 0.0], 0.6)]);
    let values = [1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0].to_vec();
    let panel = SurfacePanel::new("", v, f).with_values(values);
    let views = vec![
        View::new(0.0, 0.0),  // from +x: +y is right
        View::new(90.0, 0.0), // from +y: -x is right
        View::new(0.0, 90.0), // from +z: +y right, -x up
    ];
    let fig = figure(vec![panel], views, 160);
    let (c, layout) = render_surface(&no_path(), &fig).unwrap();
    // Mean position of the yellow and of the violet pixels in each cell.
    let centroids = |row: usize| {
        let (rect, _) = layout.cells[row][0];
        let mut sums = [[0.0; 3]; 2];
        for (x, y, p) in covered(&c, rect) {
            let k = if p[1] > 90 {
                0
            } else if p[1] < 20 {
                1
            } else {
                continue;
            };
            sums[k][0] += x as f64;
            sums[k][1] += y as f64;
            sums[k][2] += 1.0;
        }
        assert!(sums[0][2] > 100.0 && sums[1][2] > 100.0, "{sums:?}");
        sums.map(|s| (s[0] / s[2], s[1] / s[2]))
    };
    let [yel, vio] = centroids(0);
    assert!(yel.0 > vio.0 + 40.0, "az 0: yellow {yel:?} violet {vio:?}");
    assert!((yel.1 - vio.1).abs() < 5.0);
    let [yel, vio] = centroids(1);
    assert!(vio.0 > yel.0 + 40.0, "az 90: yellow {yel:?} violet {vio:?}");
    assert!((yel.1 - vio.1).abs() < 5.0);
    let [yel, vio] = centroids(2);
    assert!(
        yel.0 > vio.0 + 40.0 && vio.1 < yel.1 - 40.0,
        "top: yellow {yel:?} violet {vio:?}"
    );
}

#[test]
fn spheres_render_as_discs_at_one_shared_scale() {
    // Also the size the brief asks to be fast: 20 480 triangles per panel,
    // 3 panels x 2 views at 400 px.
    let (v, f) = icosphere(5);
    let small: Vec<[f64; 3]> = v.iter().map(|p| p.map(|c| 5.0 + 0.5 * c)).collect();
    let top = v
        .iter()
        .copied()
        .fold([0.0, 0.0, f64::NEG_INFINITY], |a, p| {
            if p[0] > a[0] {
                p
            } else {
                a
            }
        });
    let red = [220, 30, 30];
    let panels = vec![
        SurfacePanel::new("unit", v.clone(), f.clone())
            .with_marker(SurfaceMarker::new(top, "+x", red)),
        SurfacePanel::new("half, shifted", small, f.clone()),
        SurfacePanel::new("values", v.clone(), f).with_values(v.iter().map(|p| p[2]).collect()),
    ];
    let mut fig = figure(
        panels,
        vec![View::new(0.0, 0.0), View::new(180.0, 30.0)],
        400,
    );
    fig.title = "spheres".into();
    fig.value_label = "z".into();
    let t0 = std::time::Instant::now();
    let (c, layout) = render_surface(&no_path(), &fig).unwrap();
    eprintln!(
        "3 panels x 2 views of 20480 triangles at 400 px rendered in {:.1} ms",
        t0.elapsed().as_secs_f64() * 1e3
    );
    // The unit sphere is the largest: its radius spans FILL of half a cell.
    assert!((layout.scale - FILL * 200.0).abs() < 1e-9);
    for (row, cells) in layout.cells.iter().enumerate() {
        for (col, (rect, cam)) in cells.iter().enumerate() {
            let radius = if col == 1 { 0.5 } else { 1.0 } * layout.scale;
            let px = covered(&c, *rect);
            // (Markers and labels lie inside the disc: they add no pixels.)
            let n = px.len() as f64;
            let disc = std::f64::consts::PI * radius * radius;
            // The inscribed polyhedron loses well under 0.1 %.
            assert!(
                (n / disc - 1.0).abs() < 0.01,
                "view {row} panel {col}: {n} pixels vs pi r^2 = {disc:.0}"
            );
            let cx = px.iter().map(|p| p.0 as f64 + 0.5).sum::<f64>() / n;
            let cy = px.iter().map(|p| p.1 as f64 + 0.5).sum::<f64>() / n;
            assert!(
                (cx - cam.origin.0).abs() < 1.0 && (cy - cam.origin.1).abs() < 1.0,
                "view {row} panel {col}: centroid {cx},{cy} vs {:?}",
                cam.origin
            );
        }
    }
    // The marker at +x faces the first view and hides from the second: filled
    // (its colour at its centre) vs hollow (the sphere shows through).
    assert_eq!(layout.marker_visible[0][0], vec![true]);
    assert_eq!(layout.marker_visible[1][0], vec![false]);
    let (_, cam) = layout.cells[0][0];
    assert_eq!(colour_at(&c, &cam, top), red);
    let (_, cam) = layout.cells[1][0];
    let s = cam.project(top);
    let centre = c.pixel(s[0] as u32, s[1] as u32);
    assert!(centre != red && centre[0] == centre[1], "{centre:?}");
    // The ring's centre line runs half a pixel inside the disc's edge.
    let rim = c.pixel((s[0] + MARKER_SIZE / 2.0 - 0.5) as u32, s[1] as u32);
    assert_eq!(rim, red);
}

fn assert_invalid(r: Result<(), PlotError>, path: &Path, needle: &str) {
    match r {
        Err(e @ PlotError::InvalidInput { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains(&path.display().to_string()), "{msg}");
            assert!(msg.contains(needle), "'{msg}' lacks '{needle}'");
        }
        other => panic!("expected InvalidInput, got {other:?}"),
    }
}

#[test]
fn invalid_surface_figures_are_refused_and_write_nothing() {
    let dir = TempDir::new("plot-surface-invalid");
    let path = dir.path("bad.png");
    let (v, f) = tetra([0.0; 3], 1.0);
    let good = SurfacePanel::new("t", v.clone(), f.clone());
    let try_fig = |panels: Vec<SurfacePanel>, edit: &dyn Fn(&mut SurfaceFigure)| {
        let mut fig = SurfaceFigure::new("", panels);
        edit(&mut fig);
        surface_png(&path, &fig)
    };
    let none = |_: &mut SurfaceFigure| {};
    assert_invalid(try_fig(vec![], &none), &path, "no panels");
    assert_invalid(
        try_fig(vec![good.clone()], &|f| f.views.clear()),
        &path,
        "no views",
    );
    let mut p = good.clone();
    p.triangles[1] = [0, 7, 1];
    assert_invalid(
        try_fig(vec![good.clone(), p], &none),
        &path,
        "panel 1 ('t'): triangle 1 uses vertex 7, but the panel has 4 vertices",
    );
    let p = good.clone().with_values(vec![1.0; 3]);
    assert_invalid(try_fig(vec![p], &none), &path, "3 values for 4 vertices");
    let mut p = good.clone();
    p.vertices[2][1] = f64::NAN;
    assert_invalid(try_fig(vec![p], &none), &path, "vertex 2");
    let p = good
        .clone()
        .with_marker(SurfaceMarker::new([0.0, f64::INFINITY, 0.0], "m", [0; 3]));
    assert_invalid(try_fig(vec![p], &none), &path, "marker 0 ('m')");
    let p = SurfacePanel::new("", v.clone(), vec![]);
    assert_invalid(try_fig(vec![p], &none), &path, "no triangles");
    let p = good.clone().with_values(vec![f64::NAN; 4]);
    assert_invalid(try_fig(vec![p], &none), &path, "no finite value");
    let p = good.clone().with_values(vec![1.0; 4]);
    assert_invalid(
        try_fig(vec![p], &|f| f.value_range = Some((2.0, 1.0))),
        &path,
        "value range",
    );
    assert_invalid(
        try_fig(vec![good.clone()], &|f| f.panel_size = 8),
        &path,
        "panel size",
    );
    assert_invalid(
        try_fig(vec![good.clone()], &|f| f.views[0].elevation_deg = f64::NAN),
        &path,
        "view 0",
    );
    let p = SurfacePanel::new("", vec![[1.0; 3]; 3], vec![[0, 1, 2]]);
    assert_invalid(try_fig(vec![p], &none), &path, "zero");
    assert_invalid(
        try_fig(vec![good.clone(); 400], &|f| f.panel_size = 4096),
        &path,
        "400 panels x 1 views of 4096 px",
    );
    assert!(dir.entries().is_empty(), "{:?}", dir.entries());
    // A constant field is fine (centred on the scale) and gets written.
    let p = good.with_values(vec![3.0; 4]);
    try_fig(vec![p], &none).unwrap();
    assert_eq!(dir.entries(), vec!["bad.png"]);
}

/// The real bowl's boundary coloured by height, with marked points; written
/// to `target/test-scratch/surface_bowl.png` for a person to look at.
#[test]
fn bowl_height_map_example() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let read = crate::mesh::read_mesh(
        &root.join("examples/bowl/bowl.msh"),
        &crate::mesh::ReadOptions::default(),
    )
    .unwrap();
    let surf = crate::shape::TriangleSurface::from_mesh_boundary(&read.mesh);
    let z: Vec<f64> = surf.vertices.iter().map(|p| p[2]).collect();
    // Markers: the outer top edge of the rim on the +x side, and the highest
    // (inside floor) and lowest (outside bottom) vertices near the axis.
    let (lo, hi) = surf.bounding_box();
    let axis = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
    let pick = |score: &dyn Fn(&[f64; 3]) -> f64| {
        *surf
            .vertices
            .iter()
            .max_by(|a, b| score(a).total_cmp(&score(b)))
            .unwrap()
    };
    let near_axis = |p: &[f64; 3]| (p[0] - axis[0]).hypot(p[1] - axis[1]) < 0.01;
    let rim = pick(&|p| p[0] + p[2]);
    let floor = pick(&|p| {
        if near_axis(p) {
            p[2]
        } else {
            f64::NEG_INFINITY
        }
    });
    let foot = pick(&|p| {
        if near_axis(p) {
            -p[2]
        } else {
            f64::NEG_INFINITY
        }
    });
    assert!(floor[2] > foot[2] + 0.002, "floor {floor:?} foot {foot:?}");
    let mut panel = SurfacePanel::new("height", surf.vertices.clone(), surf.triangles.clone())
        .with_values(z.iter().map(|z| z * 1e3).collect());
    for (i, (p, l)) in [(rim, "rim"), (floor, "floor"), (foot, "foot")]
        .into_iter()
        .enumerate()
    {
        panel
            .markers
            .push(SurfaceMarker::new(p, l, super::super::PALETTE[i]));
    }
    let plain = SurfacePanel::new("plain", surf.vertices.clone(), surf.triangles.clone());
    let mut fig = SurfaceFigure::new(
        format!("Bowl boundary, {} triangles", surf.n_triangles()),
        vec![panel, plain],
    );
    fig.views = vec![
        View::new(30.0, 35.0),
        View::labelled(0.0, 90.0, "top"),
        View::labelled(0.0, -60.0, "from below"),
    ];
    fig.value_label = "height (mm)".into();
    fig.panel_size = 320;
    let t0 = std::time::Instant::now();
    let (c, layout) = render_surface(&no_path(), &fig).unwrap();
    eprintln!(
        "bowl: {} triangles, 2 panels x 3 views at 320 px in {:.1} ms",
        surf.n_triangles(),
        t0.elapsed().as_secs_f64() * 1e3
    );
    let out = root.join("target/test-scratch/surface_bowl.png");
    std::fs::create_dir_all(out.parent().unwrap()).unwrap();
    c.write_png(&out).unwrap();

    // From the top the floor (low, dark) is in the middle and the rim (high,
    // light) at the edge; the floor marker shows, the foot marker is hidden
    // by the floor; from below it is the other way round.
    let (_, cam) = layout.cells[1][0];
    // (20 px below the floor marker and its label.)
    let centre = c.pixel(cam.origin.0 as u32, cam.origin.1 as u32 + 20);
    let r_rim = 0.5 * (hi[0] - lo[0]) * cam.scale;
    let edge = c.pixel((cam.origin.0 - 0.97 * r_rim) as u32, cam.origin.1 as u32);
    assert!(
        lightness(edge) > lightness(centre) + 30.0,
        "rim {edge:?} vs floor {centre:?}"
    );
    assert_eq!(layout.marker_visible[1][0][1..], [true, false]);
    assert_eq!(layout.marker_visible[2][0][1..], [false, true]);
    assert!(
        layout.marker_visible[0][0][0],
        "the rim faces the first view"
    );
    // The plain panel is grey everywhere (r = g = b).
    let (rect, _) = layout.cells[0][1];
    let px = covered(&c, rect);
    assert!(px.len() > 20_000);
    assert!(px.iter().all(|p| p.2[0] == p.2[1] && p.2[1] == p.2[2]));
}

#[test]
fn corner_normals_keep_creases_and_smooth_curves() {
    // A cube: every corner normal is its face's normal (90° edges).
    let v: Vec<[f64; 3]> = (0..8)
        .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
        .collect();
    let quads = [
        [0, 2, 3, 1], // z = 0, normal -z
        [4, 5, 7, 6], // z = 1, +z
        [0, 1, 5, 4], // y = 0, -y
        [2, 6, 7, 3], // y = 1, +y
        [0, 4, 6, 2], // x = 0, -x
        [1, 3, 7, 5], // x = 1, +x
    ];
    let f: Vec<[usize; 3]> = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    let n = corner_normals(&v, &f);
    for (t, tri) in f.iter().enumerate() {
        let face = cross(sub(v[tri[1]], v[tri[0]]), sub(v[tri[2]], v[tri[0]]));
        let face = face.map(|c| c / norm(face));
        // Outward: from the cube's centre towards the face.
        assert!(dot(face, sub(v[tri[0]], [0.5; 3])) > 0.0, "triangle {t}");
        for corner in n[t] {
            assert!(norm(sub(corner, face)) < 1e-12, "triangle {t}: {corner:?}");
        }
    }
    // A sphere: corner normals follow the radius (to within 0.01, where the
    // facets of this 1280-triangle sphere are 0.05 to 0.1 off it).
    let (v, f) = icosphere(3);
    let n = corner_normals(&v, &f);
    for (tri, ns) in f.iter().zip(&n) {
        let face = cross(sub(v[tri[1]], v[tri[0]]), sub(v[tri[2]], v[tri[0]]));
        let face = face.map(|c| c / norm(face));
        for (&i, corner) in tri.iter().zip(ns) {
            let (err, facet) = (norm(sub(*corner, v[i])), norm(sub(face, v[i])));
            assert!(
                err < 0.01 && facet > 0.05,
                "{corner:?} vs {:?}: {err} (facet {facet})",
                v[i]
            );
        }
    }
}

/// Shapes side by side (the shape-from-sound figure): one scale for all, so
/// silhouettes measure as the bodies do; written to
/// `target/test-scratch/surface_shapes.png`.
#[test]
fn shapes_side_by_side_share_one_scale() {
    let (v, f) = icosphere(4);
    let ellipsoid = |a: [f64; 3]| -> Vec<[f64; 3]> {
        v.iter()
            .map(|p| [a[0] * p[0], a[1] * p[1], a[2] * p[2]])
            .collect()
    };
    let axes_of = [[1.0, 1.0, 1.0], [1.2, 0.9, 0.8], [1.3, 0.8, 0.6]];
    let panels = ["before", "after", "true"]
        .iter()
        .zip(axes_of)
        .map(|(t, a)| SurfacePanel::new(*t, ellipsoid(a), f.clone()))
        .collect();
    let mut fig = SurfaceFigure::new("Shape from sound (synthetic)", panels);
    fig.views = vec![View::new(0.0, 0.0), View::new(35.0, 25.0)];
    fig.panel_size = 200;
    let (c, layout) = render_surface(&no_path(), &fig).unwrap();
    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-scratch/surface_shapes.png");
    std::fs::create_dir_all(out.parent().unwrap()).unwrap();
    c.write_png(&out).unwrap();
    // Largest bounding sphere: the last body's 1.3 semi-axis.
    assert!((layout.scale - FILL * 100.0 / 1.3).abs() < 1e-9);
    // From +x the silhouette spans 2b wide (y) and 2c high (z), in pixels.
    for (k, a) in axes_of.iter().enumerate() {
        let (rect, _) = layout.cells[0][k];
        let px = covered(&c, rect);
        let (xmin, xmax) = (
            px.iter().map(|p| p.0).min().unwrap(),
            px.iter().map(|p| p.0).max().unwrap(),
        );
        let (ymin, ymax) = (
            px.iter().map(|p| p.1).min().unwrap(),
            px.iter().map(|p| p.1).max().unwrap(),
        );
        let (w, h) = ((xmax - xmin + 1) as f64, (ymax - ymin + 1) as f64);
        let (ew, eh) = (2.0 * a[1] * layout.scale, 2.0 * a[2] * layout.scale);
        assert!(
            (w - ew).abs() < 2.0 && (h - eh).abs() < 2.0,
            "{k}: {w}x{h} vs {ew:.1}x{eh:.1}"
        );
    }
}
