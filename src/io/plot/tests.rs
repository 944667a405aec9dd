use std::path::{Path, PathBuf};

use super::axes::{BACKGROUND, INK};
use super::line::render_line_plot;
use super::spectrogram::render_spectrogram;
use super::*;
use crate::io::test_support::TempDir;

/// Decodes a PNG written by this module: (width, height, RGB bytes).
fn decode(path: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::fs::File::open(path).unwrap());
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn px(data: &[u8], width: u32, x: i32, y: i32) -> Rgb {
    let i = (y as usize * width as usize + x as usize) * 3;
    [data[i], data[i + 1], data[i + 2]]
}

#[test]
fn font_has_the_symbols_labels_use() {
    for face in [font::Face::Regular, font::Face::Bold] {
        for ch in "αβνλΔσθρπµ²³·×−–°≈≤≥ΣAZaz09()[]/%".chars() {
            assert!(font::has_glyph(ch, face), "{ch} missing in {face:?}");
        }
    }
    // Wider text is wider, and kerning/advances are not zero.
    let st = TextStyle::new(15.0, [0; 3]);
    let (w1, h) = text_size("ν", &st);
    let (w2, _) = text_size("ν = 0.25", &st);
    assert!(w1 > 4 && w2 > 3 * w1, "{w1} {w2}");
    // Cap height of DejaVu Sans is 0.729 em.
    assert_eq!(h, 11);
    assert_eq!(text_size("", &st).0, 0);
}

#[test]
fn png_round_trip_keeps_size_and_pixels() {
    let dir = TempDir::new("plot-png");
    let path = dir.path("c.png");
    let mut c = Canvas::new(37, 23, [255, 255, 255]);
    c.fill_rect(PixelRect::new(3, 4, 10, 9), [200, 10, 20]);
    c.line(0.0, 22.5, 36.0, 0.5, [0, 0, 255], 2.0);
    c.write_png(&path).unwrap();
    let (w, h, data) = decode(&path);
    assert_eq!((w, h), (37, 23));
    assert_eq!(data, c.data());
    assert_eq!(px(&data, w, 5, 5), [200, 10, 20]);
    assert_eq!(dir.entries(), vec!["c.png"]);
}

#[test]
fn text_ink_stays_in_its_box() {
    for (text, ha, va, rotated) in [
        ("Hg 1.5k", HAlign::Left, VAlign::Top, false),
        ("frequency (Hz)", HAlign::Center, VAlign::Middle, false),
        ("-80 dB", HAlign::Right, VAlign::Bottom, false),
        ("time (s)", HAlign::Center, VAlign::Top, true),
        ("XY", HAlign::Left, VAlign::Top, true),
        ("Δf/f, ν², σ", HAlign::Left, VAlign::Middle, false),
    ] {
        let mut c = Canvas::new(300, 300, [255; 3]);
        let st = TextStyle::new(20.0, [0; 3]).align(ha, va);
        let st = if rotated { st.rotated() } else { st };
        let b = c.text(150, 150, text, &st);
        let (w, h) = text_size(text, &st);
        let (bw, bh) = if rotated { (h, w) } else { (w, h) };
        assert_eq!((b.width(), b.height()), (bw as i32, bh as i32), "{text}");
        // The anchor sits where the alignment says.
        let (ax, ay) = if rotated {
            (
                match va {
                    VAlign::Top => b.x0,
                    VAlign::Middle => b.x0 + bw as i32 / 2,
                    VAlign::Bottom => b.x1,
                },
                match ha {
                    HAlign::Left => b.y1 - 1,
                    HAlign::Center => b.y1 - 1 - bh as i32 / 2,
                    HAlign::Right => b.y0 - 1,
                },
            )
        } else {
            (
                match ha {
                    HAlign::Left => b.x0,
                    HAlign::Center => b.x0 + bw as i32 / 2,
                    HAlign::Right => b.x1,
                },
                match va {
                    VAlign::Top => b.y0,
                    VAlign::Middle => b.y0 + bh as i32 / 2,
                    VAlign::Bottom => b.y1,
                },
            )
        };
        assert!(
            (ax - 150).abs() <= 1 && (ay - 150).abs() <= 1,
            "{text}: anchor {ax},{ay} box {b:?}"
        );
        // Ink: present, and only inside the box plus the descenders (a
        // quarter em past the baseline: below it upright, right of it when
        // rotated, since a rotated glyph's bottom faces right), accents and
        // round overshoot above the cap line, and a pixel of anti-aliasing.
        let (desc, accent) = (6, 4);
        let allowed = if rotated {
            PixelRect::new(b.x0 - accent, b.y0 - 1, b.x1 + desc, b.y1 + 1)
        } else {
            PixelRect::new(b.x0 - 1, b.y0 - accent, b.x1 + 1, b.y1 + desc)
        };
        let mut ink = 0;
        for y in 0..300 {
            for x in 0..300 {
                if c.pixel(x, y) != [255; 3] {
                    ink += 1;
                    assert!(
                        allowed.contains(x as i32, y as i32),
                        "{text}: ink at {x},{y} outside {allowed:?}"
                    );
                }
            }
        }
        assert!(
            ink > 20 * text.chars().count(),
            "{text}: only {ink} ink pixels"
        );
    }
}

#[test]
fn rotated_text_reads_bottom_to_top() {
    // "L" turned 90° counter-clockwise: its stem becomes a row along the
    // bottom of the box (pointing left from the corner) and its foot a
    // column on the right.
    let mut c = Canvas::new(60, 60, [255; 3]);
    let st = TextStyle::new(30.0, [0; 3]).rotated();
    let b = c.text(10, 50, "L", &st);
    let (w, h) = text_size("L", &st);
    assert_eq!((b.width(), b.height()), (h as i32, w as i32));
    let dark = |x: i32, y: i32| c.pixel(x as u32, y as u32)[0] < 100;
    // The stem: dark along a row near the box's bottom, across the cap height.
    let stem_row = (b.y0..b.y1)
        .rev()
        .find(|&y| (b.x0 + 2..b.x1 - 2).all(|x| dark(x, y)));
    assert!(
        stem_row.is_some_and(|y| y >= b.y1 - 8),
        "no stem row in {b:?}"
    );
    // The foot: dark down a column near the box's right edge (the baseline).
    let foot_col = (b.x0..b.x1)
        .rev()
        .find(|&x| (b.y0..b.y1).filter(|&y| dark(x, y)).count() >= 8);
    assert!(
        foot_col.is_some_and(|x| x >= b.x1 - 6),
        "no foot column in {b:?}"
    );
    // The top-left of the box (the L's open corner) has no ink.
    assert!(!dark(b.x0 + 1, b.y0 + 1));
}

#[test]
fn svg_text_and_shapes_match_the_raster_layout() {
    let st = TextStyle::new(18.0, [10, 20, 30]).align(HAlign::Center, VAlign::Middle);
    let mut c = Canvas::new(200, 100, [255; 3]);
    let mut s = Svg::new(200, 100, [255; 3]);
    let bc = c.text(100, 50, "ν = 0.25", &st);
    let bs = Draw::text(&mut s, 100, 50, "ν = 0.25", &st);
    assert_eq!(bc, bs);
    Draw::set_clip(&mut s, Some(PixelRect::new(10, 10, 190, 90)));
    Draw::dashed_polyline(
        &mut s,
        &[
            (0.0, 0.0),
            (50.0, 50.0),
            (f64::NAN, 0.0),
            (60.0, 10.0),
            (90.0, 10.0),
        ],
        [200, 0, 0],
        2.0,
        &[6.0, 3.0],
    );
    Draw::hollow_marker(&mut s, 40.0, 40.0, Marker::Diamond, 10.0, [0, 0, 200]);
    Draw::set_clip(&mut s, None);
    let doc = s.finish();
    assert!(doc.starts_with("<?xml"));
    assert!(doc.trim_end().ends_with("</svg>"));
    // One glyph definition per distinct glyph (ν, =, 0, ., 2, 5: the space
    // has no outline), used once per character.
    assert_eq!(doc.matches("<path id=\"g").count(), 6, "{doc}");
    assert_eq!(doc.matches("<use ").count(), 6);
    assert!(doc.contains("stroke-dasharray=\"6,3\""));
    assert!(doc.contains("M0 0 L50 50 M60 10 L90 10"));
    assert!(doc.contains("clip-path=\"url(#clip0)\""));
    assert!(doc.contains("fill=\"none\" stroke=\"#0000c8\""));
    // Balanced groups.
    assert_eq!(doc.matches("<g").count(), doc.matches("</g>").count());
}

#[test]
fn dashes_break_a_line_into_pieces() {
    let pts = [(0.0, 0.0), (10.0, 0.0), (20.0, 0.0)];
    let d = super::canvas::dash_points(&pts, &[4.0, 2.0]);
    // Dashes [0,4], [6,10]+[10,10], [12,16], [18,20].
    let pieces: Vec<Vec<f64>> = d
        .split(|p| !p.0.is_finite())
        .filter(|p| !p.is_empty())
        .map(|p| p.iter().map(|q| q.0).collect())
        .collect();
    assert_eq!(
        pieces,
        vec![
            vec![0.0, 4.0],
            vec![6.0, 10.0],
            vec![12.0, 16.0],
            vec![18.0, 20.0]
        ]
    );
    assert_eq!(super::canvas::dash_points(&pts, &[]), pts.to_vec());
}

#[test]
fn hollow_markers_leave_their_centre() {
    let mut c = Canvas::new(40, 40, [255; 3]);
    c.hollow_marker(20.0, 20.0, Marker::Circle, 20.0, [0; 3]);
    assert_eq!(c.pixel(20, 20), [255; 3]);
    assert!(c.pixel(11, 20)[0] < 128 && c.pixel(28, 20)[0] < 128);
    c.marker(20.0, 20.0, Marker::Square, 10.0, [0; 3]);
    assert_eq!(c.pixel(20, 20), [0; 3]);
}

#[test]
fn clip_rectangle_confines_drawing() {
    let mut c = Canvas::new(50, 50, [255; 3]);
    let clip = PixelRect::new(10, 10, 30, 30);
    c.set_clip(Some(clip));
    c.line(0.0, 0.0, 50.0, 50.0, [0; 3], 3.0);
    c.marker(10.0, 10.0, Marker::Circle, 12.0, [0; 3]);
    c.text(0, 20, "WWWWWWWW", &TextStyle::new(20.0, [0; 3]));
    let mut inside = 0;
    for y in 0..50 {
        for x in 0..50 {
            if c.pixel(x, y) != [255; 3] {
                assert!(clip.contains(x as i32, y as i32), "drawn at {x},{y}");
                inside += 1;
            }
        }
    }
    assert!(inside > 50);
}

#[test]
fn lines_cover_the_right_pixels() {
    let mut c = Canvas::new(40, 20, [255; 3]);
    // A 1 px horizontal line on row 5's centre is exactly row 5.
    c.line(2.5, 5.5, 30.5, 5.5, [0; 3], 1.0);
    for x in 3..30 {
        assert_eq!(c.pixel(x, 5), [0; 3]);
        assert_eq!(c.pixel(x, 4), [255; 3]);
        assert_eq!(c.pixel(x, 6), [255; 3]);
    }
    // A long diagonal reaches both ends and passes through the middle.
    let mut c = Canvas::new(400, 200, [255; 3]);
    c.line(0.5, 0.5, 399.5, 199.5, [0; 3], 2.0);
    for (x, y) in [(0, 0), (200, 100), (399, 199)] {
        assert!(c.pixel(x, y)[0] < 128, "({x},{y}) not covered");
    }
    assert_eq!(c.pixel(200, 120), [255; 3]);
    // Far-off endpoints are clipped, not looped over.
    c.line(-1e12, 50.0, 1e12, 50.0, [0; 3], 2.0);
    assert!(c.pixel(10, 50)[0] < 128);
}

#[test]
fn nice_ticks_cover_the_range() {
    let mut seed = 12345u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..2000 {
        let mag = 10f64.powf(rnd() * 16.0 - 8.0);
        let lo = (rnd() - 0.5) * 4.0 * mag;
        let hi = lo + mag * (0.01 + rnd() * 3.0);
        let max = 2 + (rnd() * 9.0) as usize;
        let (t, step) = nice_ticks(lo, hi, max);
        // At most max + 1 ticks, unless that many would be fewer than two
        // and a finer step had to be taken.
        let coarse = super::ticks::nice_step((hi - lo) / max as f64);
        assert!(t.len() >= 2, "{lo}..{hi} max {max}: {t:?}");
        assert!(
            t.len() <= max + 1 || (step < coarse && t.len() <= 6),
            "{lo}..{hi} max {max}: {t:?}"
        );
        let e = step.log10().floor();
        let m = step / 10f64.powf(e);
        assert!(
            [1.0, 2.0, 5.0, 10.0].iter().any(|n| (m - n).abs() < 1e-6),
            "step {step}"
        );
        let tol = step * 1e-6;
        assert!(
            t[0] >= lo - tol && *t.last().unwrap() <= hi + tol,
            "{lo}..{hi}: {t:?}"
        );
        assert!(
            t[0] - lo < step + tol && hi - t.last().unwrap() < step + tol,
            "{lo}..{hi}: {t:?}"
        );
        for w in t.windows(2) {
            assert!(((w[1] - w[0]) - step).abs() <= tol * 10.0 + 1e-12 * w[1].abs());
        }
        for v in &t {
            let k = v / step;
            assert!((k - k.round()).abs() < 1e-6, "{v} not a multiple of {step}");
        }
    }
    assert_eq!(
        nice_ticks(0.0, 1.0, 5).0,
        vec![0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]
    );
    assert_eq!(
        nice_ticks(-0.3, 0.3, 6)
            .0
            .iter()
            .filter(|v| **v == 0.0)
            .count(),
        1
    );
}

#[test]
fn log_ticks_give_decades() {
    let t = log_ticks(1e-7, 1e-2, 10);
    let major: Vec<f64> = t
        .iter()
        .filter(|t| t.label.is_some())
        .map(|t| t.value)
        .collect();
    let labels: Vec<&str> = t.iter().filter_map(|t| t.label.as_deref()).collect();
    assert_eq!(major, vec![1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2]);
    assert_eq!(labels, vec!["10⁻⁷", "10⁻⁶", "10⁻⁵", "10⁻⁴", "10⁻³", "10⁻²"]);
    let minor: Vec<f64> = t
        .iter()
        .filter(|t| t.label.is_none())
        .map(|t| t.value)
        .collect();
    assert_eq!(minor.len(), 5 * 8);
    assert!(minor.iter().any(|&v| (v / 3e-5 - 1.0).abs() < 1e-12));

    let t = log_ticks(20.0, 20000.0, 8);
    let labels: Vec<&str> = t.iter().filter_map(|t| t.label.as_deref()).collect();
    assert_eq!(labels, vec!["100", "1k", "10k"]);
    assert!(t.iter().all(|t| t.value >= 20.0 && t.value <= 20000.0));
    assert!(t
        .iter()
        .any(|t| t.label.is_none() && (t.value - 20.0).abs() < 1e-9));

    // Many decades: a label every few, still on decades.
    let t = log_ticks(1e-30, 1e10, 6);
    let major: Vec<f64> = t
        .iter()
        .filter(|t| t.label.is_some())
        .map(|t| t.value)
        .collect();
    assert!(major.len() >= 3 && major.len() <= 7, "{major:?}");
    for v in major {
        let e = v.log10();
        assert!((e - e.round()).abs() < 1e-9);
    }
    // Under two decades: 1-2-5 labels.
    let labels: Vec<String> = log_ticks(50.0, 400.0, 8)
        .into_iter()
        .filter_map(|t| t.label)
        .collect();
    assert_eq!(labels, vec!["50", "100", "200"]);
}

#[test]
fn tick_labels_are_compact() {
    assert_eq!(
        format_ticks(&[0.0, 500.0, 1000.0, 1500.0], 500.0),
        ["0", "500", "1k", "1.5k"]
    );
    assert_eq!(
        format_ticks(&[0.0, 0.1, 0.2, 0.30000000000000004], 0.1),
        ["0", "0.1", "0.2", "0.3"]
    );
    assert_eq!(format_ticks(&[-1.0, 0.0, 1.0], 1.0), ["-1", "0", "1"]);
    assert_eq!(
        format_ticks(&[1e-7, 1.5e-7, 2e-7], 5e-8),
        ["10⁻⁷", "1.5·10⁻⁷", "2·10⁻⁷"]
    );
    assert_eq!(format_ticks(&[2e6, 2.5e6], 5e5), ["2M", "2.5M"]);
    assert_eq!(format_ticks(&[0.001, 0.002], 0.001), ["0.001", "0.002"]);
    assert_eq!(
        format_log_ticks(&[0.01, 1.0, 100.0, 1e4]),
        ["0.01", "1", "100", "10k"]
    );
}

#[test]
fn scientific_labels_use_superscripts() {
    assert_eq!(scientific(7.2e10, 2), "7.20·10¹⁰");
    assert_eq!(scientific(-1.5e-8, 1), "-1.5·10⁻⁸");
    assert_eq!(scientific(9.999e4, 2), "1.00·10⁵");
    assert_eq!(scientific(3.25, 2), "3.25");
    assert_eq!(scientific(0.0, 2), "0");
}

#[test]
fn colormap_lightness_rises() {
    // In steps of 1/64 (finer steps are within the u8 rounding of the
    // colours), L* rises, and evenly: no step is more than twice another.
    let l: Vec<f64> = (0..=64)
        .map(|k| colormap::lightness(colormap(k as f64 / 64.0)))
        .collect();
    let steps: Vec<f64> = l.windows(2).map(|w| w[1] - w[0]).collect();
    let (lo, hi) = steps
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &d| (a.min(d), b.max(d)));
    assert!(
        lo > 0.0 && hi < 2.0 * lo,
        "L* steps range {lo}..{hi}: {l:?}"
    );
    assert_eq!(colormap(f64::NAN), colormap(0.0));
    assert_eq!(colormap(-5.0), colormap(0.0));
    assert_eq!(colormap(7.0), colormap(1.0));
}

/// A panel of `-100 dB` with one 0 dB cell.
fn one_bright_cell(n_frames: usize, n_bins: usize, bright: (usize, usize)) -> Vec<f64> {
    let mut db = vec![-100.0; n_frames * n_bins];
    db[bright.0 * n_bins + bright.1] = 0.0;
    db
}

/// The lightest pixels of `plot` (all that tie): a uniform cell of the top
/// colour with nearest resampling, the tip of the tent with bilinear.
fn bright_pixels(data: &[u8], w: u32, plot: PixelRect) -> Vec<(i32, i32)> {
    let mut best = f64::NEG_INFINITY;
    let mut out = Vec::new();
    for y in plot.y0..plot.y1 {
        for x in plot.x0..plot.x1 {
            let l = colormap::lightness(px(data, w, x, y));
            if l > best + 1e-9 {
                best = l;
                out.clear();
            }
            if (l - best).abs() <= 1e-9 {
                out.push((x, y));
            }
        }
    }
    out
}

#[test]
fn spectrogram_puts_a_bright_cell_where_the_axes_say() {
    let dir = TempDir::new("plot-spec");
    let (nf, nb, dt, t0, df) = (50, 64, 0.02, 0.01, 100.0);
    let (fi, bj) = (20, 30);
    let (t, f) = (t0 + fi as f64 * dt, bj as f64 * df);
    let db = one_bright_cell(nf, nb, (fi, bj));
    let panel = SpectrogramPanel {
        title: "p".into(),
        db: &db,
        n_frames: nf,
        n_bins: nb,
        time_step_s: dt,
        time_offset_s: t0,
        freq_step_hz: df,
    };
    for resampling in [Resampling::Nearest, Resampling::Bilinear] {
        let mut fig = SpectrogramFigure::new("one cell", vec![panel.clone(), panel.clone()]);
        fig.panel_width = 400;
        fig.panel_height = 300;
        fig.resampling = resampling;
        let path = dir.path("s.png");
        spectrogram_png(&path, &fig).unwrap();
        let (canvas, layout) = render_spectrogram(&path, &fig).unwrap();
        let (w, h, data) = decode(&path);
        assert_eq!((w, h), (canvas.width(), canvas.height()));
        assert_eq!(data, canvas.data());
        for (plot, xm, ym) in &layout.panels {
            let (ex, ey) = (xm.to_px(t), ym.to_px(f));
            let bright = bright_pixels(&data, w, *plot);
            assert!(!bright.is_empty(), "{resampling:?}: no bright pixel");
            let n = bright.len() as f64;
            let cx = bright.iter().map(|p| p.0 as f64 + 0.5).sum::<f64>() / n;
            let cy = bright.iter().map(|p| p.1 as f64 + 0.5).sum::<f64>() / n;
            assert!(
                (cx - ex).abs() <= 0.75 && (cy - ey).abs() <= 0.75,
                "{resampling:?}: bright at {cx},{cy}, axes say {ex},{ey}"
            );
            if resampling == Resampling::Nearest {
                assert!(bright
                    .iter()
                    .all(|&(x, y)| px(&data, w, x, y) == colormap(1.0)));
                // The cell's whole extent, ±half a step, and nothing else.
                let (x0, x1) = (xm.to_px(t - dt / 2.0), xm.to_px(t + dt / 2.0));
                let (y0, y1) = (ym.to_px(f + df / 2.0), ym.to_px(f - df / 2.0));
                for &(x, y) in &bright {
                    let (pcx, pcy) = (x as f64 + 0.5, y as f64 + 0.5);
                    assert!(
                        pcx >= x0 - 1.0 && pcx <= x1 + 1.0 && pcy >= y0 - 1.0 && pcy <= y1 + 1.0
                    );
                }
                let expect = ((x1 - x0) * (y1 - y0)).round();
                assert!(
                    (n - expect).abs() <= (x1 - x0) + (y1 - y0) + 1.0,
                    "{n} bright pixels, expected ~{expect}"
                );
            }
        }
    }
}

#[test]
fn spectrogram_ticks_sit_on_their_values() {
    let dir = TempDir::new("plot-ticks");
    let db = one_bright_cell(30, 40, (3, 4));
    let panel = SpectrogramPanel {
        title: String::new(),
        db: &db,
        n_frames: 30,
        n_bins: 40,
        time_step_s: 0.05,
        time_offset_s: 0.0,
        freq_step_hz: 250.0,
    };
    let fig = SpectrogramFigure::new("", vec![panel]);
    let path = dir.path("t.png");
    let (c, layout) = render_spectrogram(&path, &fig).unwrap();
    let (plot, xm, ym) = layout.panels[0];
    assert!(layout.x_ticks.len() >= 3);
    for t in &layout.x_ticks {
        let x = xm.tick_pixel(t.value);
        assert_eq!(
            x,
            xm.to_px(t.value).floor().min(plot.x1 as f64 - 1.0) as i32
        );
        assert_eq!(
            c.pixel(x as u32, plot.y1 as u32 + 3),
            INK,
            "x tick {} at column {x}",
            t.value
        );
    }
    // The frequency axis runs 0..(40-1)·250 Hz = 9.75 kHz, so it is in kHz.
    assert_eq!((ym.lo, ym.hi), (0.0, 9750.0));
    for f in [0.0, 2000.0, 4000.0, 8000.0] {
        let y = ym.tick_pixel(f);
        assert_eq!(
            c.pixel(plot.x0 as u32 - 4, y as u32),
            INK,
            "y tick {f} Hz at row {y}"
        );
    }
    // Ticks leave the gaps between them blank.
    let y = ym.tick_pixel(1000.0);
    assert_eq!(c.pixel(plot.x0 as u32 - 4, y as u32), BACKGROUND);
}

#[test]
fn spectrogram_finer_than_pixels_keeps_the_peak() {
    let dir = TempDir::new("plot-fine");
    let (nf, nb) = (3000, 8);
    let db = one_bright_cell(nf, nb, (1234, 3));
    let panel = SpectrogramPanel {
        title: String::new(),
        db: &db,
        n_frames: nf,
        n_bins: nb,
        time_step_s: 0.001,
        time_offset_s: 0.0,
        freq_step_hz: 1000.0,
    };
    let mut fig = SpectrogramFigure::new("", vec![panel]);
    fig.panel_width = 200;
    let path = dir.path("f.png");
    let (c, layout) = render_spectrogram(&path, &fig).unwrap();
    let (plot, xm, _) = layout.panels[0];
    let bright = bright_pixels(c.data(), c.width(), plot);
    assert!(!bright.is_empty());
    let ex = xm.to_px(1.234).floor() as i32;
    assert!(
        bright.iter().all(|p| (p.0 - ex).abs() <= 1),
        "bright columns {bright:?}, expected {ex}"
    );
}

fn tiny_panel(db: &[f64], n_frames: usize, n_bins: usize) -> SpectrogramPanel<'_> {
    SpectrogramPanel {
        title: "x".into(),
        db,
        n_frames,
        n_bins,
        time_step_s: 0.01,
        time_offset_s: 0.0,
        freq_step_hz: 10.0,
    }
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
fn invalid_figures_are_refused_and_write_nothing() {
    let dir = TempDir::new("plot-invalid");
    let path = dir.path("bad.png");
    let db = vec![0.0; 12];
    assert_invalid(
        spectrogram_png(
            &path,
            &SpectrogramFigure::new("", vec![tiny_panel(&db, 5, 3)]),
        ),
        &path,
        "12 dB values for 5 frames x 3 bins",
    );
    assert_invalid(
        spectrogram_png(&path, &SpectrogramFigure::new("", vec![])),
        &path,
        "no panels",
    );
    let mut p = tiny_panel(&db, 4, 3);
    p.time_step_s = f64::NAN;
    assert_invalid(
        spectrogram_png(&path, &SpectrogramFigure::new("", vec![p])),
        &path,
        "time step",
    );
    let nan = vec![f64::NEG_INFINITY; 12];
    assert_invalid(
        spectrogram_png(
            &path,
            &SpectrogramFigure::new("", vec![tiny_panel(&nan, 4, 3)]),
        ),
        &path,
        "no finite dB",
    );
    let mut f = SpectrogramFigure::new("", vec![tiny_panel(&db, 4, 3)]);
    f.db_min = Some(10.0);
    f.db_max = Some(0.0);
    assert_invalid(spectrogram_png(&path, &f), &path, "increasing");

    let mut fig = LineFigure::new("t", "x", "y");
    assert_invalid(line_plot_png(&path, &fig), &path, "no series");
    fig.series
        .push(Series::line("a", vec![1.0, 2.0, 3.0], vec![1.0, 2.0]));
    assert_invalid(
        line_plot_png(&path, &fig),
        &path,
        "3 x values but 2 y values",
    );
    fig.series[0] = Series::line("a", vec![1.0, f64::NAN], vec![f64::INFINITY, 2.0]);
    assert_invalid(
        line_plot_png(&path, &fig),
        &path,
        "no series has a single valid",
    );
    fig.series[0] = Series::line("a", vec![1.0, 2.0], vec![-1.0, 0.0]);
    fig.y_scale = AxisScale::Log;
    assert_invalid(line_plot_png(&path, &fig), &path, "log axis");
    fig.y_scale = AxisScale::Linear;
    fig.x_range = Some((3.0, 1.0));
    assert_invalid(line_plot_png(&path, &fig), &path, "x range");
    assert!(dir.entries().is_empty(), "{:?}", dir.entries());
}

#[test]
fn unsupported_extensions_are_refused_up_front() {
    let dir = TempDir::new("plot-format");
    let mut fig = LineFigure::new("t", "x", "y");
    fig.series
        .push(Series::line("a", vec![1.0, 2.0], vec![1.0, 2.0]));
    for name in ["x.pdf", "x", "x.PNG.txt"] {
        let path = dir.path(name);
        let e = line_plot(&path, &fig).unwrap_err();
        assert!(matches!(e, PlotError::UnsupportedFormat { .. }), "{e:?}");
        let msg = e.to_string();
        assert!(msg.contains(name) && msg.contains(".png, .svg"), "{msg}");
    }
    // Rasters take .png only; the case of the extension does not matter.
    let db = vec![0.0; 12];
    let sfig = SpectrogramFigure::new("", vec![tiny_panel(&db, 4, 3)]);
    let e = spectrogram_png(&dir.path("s.svg"), &sfig).unwrap_err();
    assert!(e.to_string().contains("use .png"), "{e}");
    assert!(dir.entries().is_empty(), "{:?}", dir.entries());
    spectrogram_png(&dir.path("s.PNG"), &sfig).unwrap();
    assert_eq!(
        ImageFormat::for_path(Path::new("a/b.Svg"), LINE_PLOT_FORMATS).unwrap(),
        ImageFormat::Svg
    );
}

#[test]
fn line_plot_svg_has_the_png_layout() {
    let dir = TempDir::new("plot-svg");
    let mut fig = LineFigure::new("Δf", "frequency (Hz)", "σ²");
    fig.series.push(Series::markers(
        "α",
        vec![1.0, 2.0, 3.0],
        vec![1.0, 4.0, 9.0],
        Marker::Circle,
    ));
    let svg_path = dir.path("l.svg");
    line_plot(&svg_path, &fig).unwrap();
    let doc = std::fs::read_to_string(&svg_path).unwrap();
    assert!(
        doc.contains(r#"width="1600" height="1000""#),
        "{}",
        &doc[..200]
    );
    let (_, lp) = render_line_plot(&svg_path, &fig).unwrap();
    let (_, ls) = super::line::render_line_plot_svg(&svg_path, &fig).unwrap();
    assert_eq!((lp.plot, lp.legend), (ls.plot, ls.legend));
    // The markers sit where the axes say.
    let (cx, cy) = (lp.x.to_px(2.0), lp.y.to_px(4.0));
    let needle = format!(r#"<circle cx="{}" cy="{}""#, fmt2(cx), fmt2(cy));
    assert!(doc.contains(&needle), "{needle}");
}

/// A number as the SVG writer formats it (two decimals, no trailing zeros).
fn fmt2(v: f64) -> String {
    let s = format!("{v:.2}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

#[test]
fn legend_leaves_the_data_and_lists_only_drawn_series() {
    let dir = TempDir::new("plot-legend");
    let path = dir.path("l.png");
    // Twelve series that fill every corner: the legend must go outside.
    let mut fig = LineFigure::new("", "t", "e");
    fig.y_scale = AxisScale::Log;
    let t: Vec<f64> = (0..50).map(|k| k as f64).collect();
    for b in 0..12 {
        fig.series.push(Series::line(
            format!("band {b}"),
            t.clone(),
            t.iter()
                .map(|&x| 10f64.powf(-(b as f64) * 0.5 + 0.1 * (x * (b + 1) as f64).sin()))
                .collect(),
        ));
    }
    // An empty series and one with nothing valid on the log axis.
    fig.series.push(Series::line("empty", vec![], vec![]));
    fig.series
        .push(Series::line("negative", vec![1.0, 2.0], vec![-1.0, -2.0]));
    let (_, l) = render_line_plot(&path, &fig).unwrap();
    assert!(l.legend_outside);
    let lg = l.legend.unwrap();
    assert!(lg.x0 > l.plot.x1, "{lg:?} {:?}", l.plot);
    assert_eq!(l.legend_entries, (0..12).collect::<Vec<_>>());
    // Series past the palette are told apart by dashes.
    let looks: Vec<_> = (0..12).map(|k| fig.series[k].look(k)).collect();
    for i in 0..12 {
        for j in 0..i {
            assert_ne!(looks[i], looks[j], "series {i} and {j} look alike");
        }
    }
    // A figure with an empty corner keeps its legend inside.
    let mut fig = LineFigure::new("", "x", "y");
    fig.series
        .push(Series::line("rise", vec![0.0, 1.0], vec![0.0, 1.0]));
    let (_, l) = render_line_plot(&path, &fig).unwrap();
    assert!(!l.legend_outside);
    let lg = l.legend.unwrap();
    assert_eq!(l.plot.intersect(&lg), lg);
}

#[test]
fn failed_writes_leave_no_file() {
    let dir = TempDir::new("plot-atomic");
    let canvas = Canvas::new(8, 8, [0; 3]);
    // Missing directory: an error naming the path, nothing anywhere.
    let missing: PathBuf = dir.path("no/such/dir/x.png");
    let e = canvas.write_png(&missing).unwrap_err();
    // The atomic writer names the cause when it finds one (io::atomic), else the raw error.
    assert!(
        matches!(e, PlotError::Fs { .. } | PlotError::WriteFailed { .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains("x.png"), "{e}");
    assert!(dir.entries().is_empty());
    // The target is a directory: the temporary is written, the rename
    // fails, and the temporary must be gone again.
    let target = dir.path("taken.png");
    std::fs::create_dir(&target).unwrap();
    let e = canvas.write_png(&target).unwrap_err();
    assert!(
        matches!(e, PlotError::Fs { .. } | PlotError::WriteFailed { .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains("taken.png"), "{e}");
    assert_eq!(dir.entries(), vec!["taken.png"]);
    assert!(target.is_dir());
    // No file name at all.
    assert!(matches!(
        canvas.write_png(Path::new("/")),
        Err(PlotError::InvalidInput { .. })
    ));
}

#[test]
fn line_plot_points_land_on_their_axis_positions() {
    let dir = TempDir::new("plot-line");
    let path = dir.path("l.png");
    let mut fig = LineFigure::new("t", "frequency (Hz)", "decay rate (1/s)");
    fig.x_scale = AxisScale::Log;
    fig.y_scale = AxisScale::Log;
    let red = [200, 0, 0];
    fig.series.push(
        Series::markers(
            "m",
            vec![100.0, 1000.0, 10000.0, f64::NAN, -5.0],
            vec![1.0, 10.0, 300.0, 4.0, 4.0],
            Marker::Square,
        )
        .with_color(red),
    );
    fig.series
        .push(Series::line("", vec![100.0, 10000.0], vec![2.0, 200.0]));
    line_plot_png(&path, &fig).unwrap();
    let (w, h, data) = decode(&path);
    assert_eq!((w, h), (fig.width, fig.height));
    let (_, layout) = render_line_plot(&path, &fig).unwrap();
    for (x, y) in [(100.0, 1.0), (1000.0, 10.0), (10000.0, 300.0)] {
        let (cx, cy) = (layout.x.to_px(x), layout.y.to_px(y));
        // Markers at the plot edge are half clipped; probe inward.
        let px_ = (cx.floor() as i32).clamp(layout.plot.x0, layout.plot.x1 - 1);
        let py_ = (cy.floor() as i32).clamp(layout.plot.y0, layout.plot.y1 - 1);
        assert_eq!(
            px(&data, w, px_, py_),
            red,
            "marker for ({x}, {y}) at {cx},{cy}"
        );
    }
    // Decade labels on both axes.
    let xl: Vec<&str> = layout
        .x_ticks
        .iter()
        .filter_map(|t| t.label.as_deref())
        .collect();
    assert!(xl.contains(&"1k"), "{xl:?}");
    // The data range (padded) is what the axes show.
    assert!(layout.x.lo < 100.0 && layout.x.hi > 10000.0 && layout.x.hi < 20000.0);
    // Unlabelled series stay out of the legend, which must not sit on data.
    let lg = layout.legend.unwrap();
    let look = super::axes::Look::new(fig.scale);
    assert_eq!(lg.height(), 2 * look.px(10.0) + look.text_h());
    assert_eq!(layout.legend_entries, vec![0]);
    for (x, y) in [(100.0, 1.0), (1000.0, 10.0), (10000.0, 300.0)] {
        let (cx, cy) = (layout.x.to_px(x), layout.y.to_px(y));
        assert!(!lg.contains(cx as i32, cy as i32), "legend on ({x}, {y})");
    }
}

/// Writes the example figures when `DIFFSOUND_PLOT_EXAMPLES` names a
/// directory (for looking at them); otherwise does nothing.
#[test]
fn write_examples() {
    let Ok(dir) = std::env::var("DIFFSOUND_PLOT_EXAMPLES") else {
        return;
    };
    let dir = PathBuf::from(dir);
    std::fs::create_dir_all(&dir).unwrap();
    examples::write_all(&dir);
}

mod examples {
    use super::super::*;
    use std::path::Path;

    /// A dB image of decaying partials (frequency, amplitude, decay rate
    /// 1/s) plus a falling chirp, with a Gaussian window lobe ~2 bins wide
    /// and a noise floor; stands in for an STFT.
    fn synth(
        n_frames: usize,
        n_bins: usize,
        dt: f64,
        df: f64,
        noise_db: f64,
        seed: u64,
        detune: f64,
    ) -> Vec<f64> {
        let partials = [
            (440.0, 1.0, 3.0),
            (1180.0, 0.6, 6.0),
            (2350.0, 0.4, 12.0),
            (3900.0, 0.3, 25.0),
            (6100.0, 0.2, 40.0),
        ];
        let mut s = seed;
        let mut rnd = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut db = vec![0.0; n_frames * n_bins];
        for i in 0..n_frames {
            let t = i as f64 * dt;
            for j in 0..n_bins {
                let f = j as f64 * df;
                let mut p = 10f64.powf(noise_db / 10.0) * (0.5 + rnd());
                if t >= 0.1 {
                    let tt = t - 0.1;
                    for &(f0, a, d) in &partials {
                        let g = ((f - f0 * detune) / (1.5 * df)).powi(2);
                        p += (a * (-d * tt).exp()).powi(2) * (-g).exp();
                    }
                    let fc = 7000.0 * (-2.0 * tt).exp() + 800.0;
                    let g = ((f - fc) / (2.0 * df)).powi(2);
                    p += (0.05 * (-1.5 * tt).exp()).powi(2) * (-g).exp();
                }
                db[i * n_bins + j] = 10.0 * p.log10();
            }
        }
        db
    }

    pub(super) fn write_all(dir: &Path) {
        let (nf, nb, dt, df) = (180, 257, 0.01, 8000.0 / 256.0);
        let rec = synth(nf, nb, dt, df, -75.0, 7, 1.0);
        let ren = synth(150, nb, dt, df, -160.0, 9, 1.01);
        let panels = vec![
            SpectrogramPanel {
                title: "recording".into(),
                db: &rec,
                n_frames: nf,
                n_bins: nb,
                time_step_s: dt,
                time_offset_s: 0.0,
                freq_step_hz: df,
            },
            SpectrogramPanel {
                title: "rendered".into(),
                db: &ren,
                n_frames: 150,
                n_bins: nb,
                time_step_s: dt,
                time_offset_s: 0.0,
                freq_step_hz: df,
            },
        ];
        let fig = SpectrogramFigure::new("Bowl, mic 1: recording vs rendered", panels);
        spectrogram_png(&dir.join("spectrogram.png"), &fig).unwrap();

        // Low-frequency crop in Hz, bilinear.
        let mut fig = fig.clone();
        fig.max_freq_hz = Some(1500.0);
        fig.resampling = Resampling::Bilinear;
        fig.panels.truncate(1);
        fig.title = "First partials (bilinear, 0-1.5 kHz)".into();
        spectrogram_png(&dir.join("spectrogram_crop.png"), &fig).unwrap();

        // Several microphones, small panels.
        let mics: Vec<Vec<f64>> = (0..4)
            .map(|m| {
                synth(
                    120,
                    129,
                    0.015,
                    12000.0 / 128.0,
                    -70.0 - 5.0 * m as f64,
                    m,
                    1.0 + 0.004 * m as f64,
                )
            })
            .collect();
        let panels = mics
            .iter()
            .enumerate()
            .map(|(m, db)| SpectrogramPanel {
                title: format!("mic {}", m + 1),
                db,
                n_frames: 120,
                n_bins: 129,
                time_step_s: 0.015,
                time_offset_s: 0.05,
                freq_step_hz: 12000.0 / 128.0,
            })
            .collect();
        let mut fig = SpectrogramFigure::new("Four microphones", panels);
        fig.panel_width = 260;
        fig.panel_height = 200;
        fig.db_max = Some(0.0);
        fig.db_min = Some(-60.0);
        spectrogram_png(&dir.join("spectrogram_mics.png"), &fig).unwrap();

        // Rayleigh damping d(f) = (alpha + beta (2 pi f)^2) / 2 and measured rates.
        let (alpha, beta) = (4.0, 2.0e-8);
        let d = |f: f64| (alpha + beta * (2.0 * std::f64::consts::PI * f).powi(2)) / 2.0;
        let fs: Vec<f64> = (0..200)
            .map(|k| 100.0 * 10f64.powf(k as f64 / 199.0 * 2.3))
            .collect();
        let modes = [
            310.0, 520.0, 890.0, 1240.0, 1730.0, 2650.0, 3880.0, 5210.0, 7430.0, 9900.0, 13800.0,
        ];
        let jitter = [1.2, 0.85, 1.1, 0.95, 1.3, 0.9, 1.05, 0.8, 1.15, 0.9, 1.1];
        let mut fig = LineFigure::new(
            "Damping: Rayleigh fit vs measured decay",
            "frequency (Hz)",
            "decay rate d (1/s)",
        );
        fig.x_scale = AxisScale::Log;
        fig.y_scale = AxisScale::Log;
        fig.series.push(Series::line(
            "Rayleigh d(f), α = 4 s⁻¹, β = 2·10⁻⁸ s",
            fs.clone(),
            fs.iter().map(|&f| d(f)).collect(),
        ));
        fig.series.push(Series::markers(
            "measured modes",
            modes.to_vec(),
            modes.iter().zip(jitter).map(|(&f, j)| d(f) * j).collect(),
            Marker::Circle,
        ));
        fig.series.push(Series::markers(
            "rejected (low SNR)",
            vec![2100.0, 11000.0],
            vec![d(2100.0) * 2.5, d(11000.0) * 0.4],
            Marker::Cross,
        ));
        line_plot(&dir.join("damping.png"), &fig).unwrap();
        line_plot(&dir.join("damping.svg"), &fig).unwrap();
        fig.x_scale = AxisScale::Linear;
        fig.x_range = Some((0.0, 16000.0));
        fig.title = "Damping, linear frequency axis".into();
        fig.legend = LegendPlacement::BottomRight;
        line_plot_png(&dir.join("damping_linlog.png"), &fig).unwrap();

        // Loss history on a log y axis.
        let it: Vec<f64> = (0..400).map(|k| k as f64).collect();
        let loss: Vec<f64> = it
            .iter()
            .map(|&k| 3.0 * (-k / 40.0).exp() + 2e-4 * (1.0 + 0.3 * (k / 7.0).sin()))
            .collect();
        let val: Vec<f64> = it.iter().map(|&k| 3.5 * (-k / 45.0).exp() + 5e-4).collect();
        let mut fig = LineFigure::new("Fit loss", "iteration", "loss");
        fig.y_scale = AxisScale::Log;
        fig.series.push(Series::line("train", it.clone(), loss));
        fig.series.push(Series::line("validation", it, val));
        line_plot_png(&dir.join("loss.png"), &fig).unwrap();

        // Frequency errors per mode, as stems.
        let idx: Vec<f64> = (1..=14).map(|k| k as f64).collect();
        let err: Vec<f64> = idx
            .iter()
            .map(|&k| 2.5 * (k * 1.7).sin() * (1.0 + k / 10.0))
            .collect();
        let mut fig = LineFigure::new("Frequency error per mode", "mode", "Δf/f (%)");
        fig.series.push(Series::new(
            "rendered - measured",
            idx,
            err,
            SeriesStyle::Stems(Marker::Diamond),
        ));
        line_plot_png(&dir.join("freq_error.png"), &fig).unwrap();

        // Residuals: baseline hollow, final filled, one colour per quantity.
        let f: Vec<f64> = (0..12).map(|k| 300.0 * 1.35f64.powi(k)).collect();
        let mut fig = LineFigure::new(
            "standardised residuals: baseline (hollow) vs final (filled)",
            "observed frequency (Hz)",
            "z = residual / σ",
        );
        fig.x_scale = AxisScale::Log;
        for (q, (name, m)) in [("ln f", Marker::Circle), ("ln d", Marker::Square)]
            .into_iter()
            .enumerate()
        {
            let base: Vec<f64> = f
                .iter()
                .map(|&x| 3.0 * (x / 500.0 + q as f64).sin())
                .collect();
            fig.series.push(
                Series::markers(format!("{name}, baseline"), f.clone(), base.clone(), m)
                    .with_color(PALETTE[q])
                    .with_hollow(true),
            );
            fig.series.push(
                Series::markers(
                    format!("{name}, final"),
                    f.clone(),
                    base.iter().map(|v| 0.3 * v).collect(),
                    m,
                )
                .with_color(PALETTE[q])
                .with_hollow(false),
            );
        }
        line_plot(&dir.join("residuals.png"), &fig).unwrap();

        // Twelve bands and their floors: legend outside, dashed floors.
        let t: Vec<f64> = (0..100).map(|k| k as f64 * 0.01).collect();
        let mut fig = LineFigure::new(
            "residual energy per band vs pre-roll floor",
            "time after the strike (s)",
            "energy (full scale²)",
        );
        fig.y_scale = AxisScale::Log;
        for (b, &c) in PALETTE.iter().enumerate().take(6) {
            fig.series.push(
                Series::line(
                    format!("{}–{} Hz", 500 * (b + 1), 500 * (b + 2)),
                    t.clone(),
                    t.iter()
                        .map(|&x| 1e-3 * 10f64.powf(-(b as f64)) * (-3.0 * x).exp() + 1e-9)
                        .collect(),
                )
                .with_color(c),
            );
            fig.series.push(
                Series::line(
                    format!("{}–{} Hz floor", 500 * (b + 1), 500 * (b + 2)),
                    vec![0.0, 1.0],
                    vec![2e-8 * 10f64.powf(-(b as f64) / 2.0); 2],
                )
                .with_color(c)
                .with_dash(Dash::Dashed),
            );
        }
        line_plot(&dir.join("envelopes.png"), &fig).unwrap();
        line_plot(&dir.join("envelopes.svg"), &fig).unwrap();
    }
}

/// The first and last columns with ink in the title band of the PNG at `path` (from the top
/// margin down one title line), and the image width.
fn title_ink(path: &Path, look: &super::axes::Look) -> (i32, i32, i32) {
    let (w, _, data) = decode(path);
    let (top, bottom) = (
        look.margin(),
        look.margin() + look.title_h() + look.descent(),
    );
    let inked = |x: i32| (top..bottom).any(|y| px(&data, w, x, y) != BACKGROUND);
    let columns: Vec<i32> = (0..w as i32).filter(|&x| inked(x)).collect();
    (columns[0], *columns.last().unwrap(), w as i32)
}

#[test]
fn a_title_wider_than_the_image_is_shrunk_to_fit_between_the_margins() {
    let dir = TempDir::new("plot-title");
    let title = "standardised residuals per mode: baseline vs final (contact_duration, \
                 non_rayleigh_damping, reverb_noise, beating_pair, added_mass, pitch_glide)";
    let mut fig = LineFigure::new(title, "x", "y");
    fig.series
        .push(Series::line("a", vec![1.0, 2.0], vec![1.0, 2.0]));
    let look = super::axes::Look::new(fig.scale);
    // At the usual size this title is wider than the image.
    assert!(text_size(title, &look.title_style()).0 as i32 > fig.width as i32);
    let path = dir.path("t.png");
    line_plot_png(&path, &fig).unwrap();
    let (first, last, w) = title_ink(&path, &look);
    // Ink spans most of the width and stays inside the margins (not cut at either edge).
    assert!(
        first >= look.margin() - 1 && last <= w - look.margin(),
        "{first} {last}"
    );
    assert!(last - first > w / 2, "{first} {last}");
    // A title that fits keeps the usual size.
    let short = look.title_style_within("t", fig.width as i32);
    assert_eq!(short.size, look.title_style().size);
}

#[test]
fn a_spectrograms_title_wider_than_the_image_is_shrunk_to_fit_between_the_margins() {
    let dir = TempDir::new("plot-spec-title");
    let db = vec![0.0; 12];
    let title = "where the modes do not explain the recording, and what every microphone \
                 heard beside it, channel by channel, band by band";
    let fig = SpectrogramFigure::new(title, vec![tiny_panel(&db, 4, 3)]);
    let look = super::axes::Look::new(fig.scale);
    let path = dir.path("s.png");
    spectrogram_png(&path, &fig).unwrap();
    let (first, last, w) = title_ink(&path, &look);
    assert!(text_size(title, &look.title_style()).0 as i32 > w);
    assert!(
        first >= look.margin() - 1 && last <= w - look.margin(),
        "{first} {last}"
    );
}
