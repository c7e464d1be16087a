//! The reader on broken input (cut, mutated, inconsistent files), on what real files do that
//! the format does not say, and its throughput.

use super::*;

// ---------------------------------------------------------------------------------------------
// Broken input

/// Start offsets of the binary commands of s_Cylinder_ex.cli (it only has 128 and 129), each with
/// the number of layers begun before it, plus the end.
fn cylinder_commands(bytes: &[u8]) -> (usize, Vec<(usize, usize)>) {
    let data = bytes.windows(11).position(|w| w == b"$$HEADEREND").unwrap() + 11;
    let u16_at = |i: usize| usize::from(u16::from_le_bytes([bytes[i], bytes[i + 1]]));
    let mut out = Vec::new();
    let (mut i, mut layers) = (data, 0);
    while i < bytes.len() {
        out.push((i, layers));
        match u16_at(i) {
            128 => {
                layers += 1;
                i += 4;
            }
            129 => i += 8 + 4 * u16_at(i + 6),
            other => panic!("command {other} at {i}"),
        }
    }
    assert_eq!(i, bytes.len());
    out.push((i, layers));
    (data, out)
}

#[test]
fn every_cut_of_the_binary_file_is_an_error_or_a_prefix_never_a_panic() {
    let bytes = bytes_of("s_Cylinder_ex.cli");
    let (data, commands) = cylinder_commands(&bytes);
    for cut in 0..=bytes.len() {
        let r = vectors::read_bytes(&bytes[..cut], "s_Cylinder_ex.cli");
        if cut < data {
            let e = r.expect_err("a header cut short must fail");
            assert!(e.line().is_some(), "cut {cut}: {e}");
            continue;
        }
        match commands.iter().find(|(start, _)| *start == cut) {
            Some(&(_, layers)) => {
                let f = r.unwrap_or_else(|e| panic!("cut {cut} at a command boundary: {e}"));
                assert_eq!(f.layers.len(), layers, "cut {cut}");
            }
            None => {
                let e = r.expect_err("a command cut short must fail");
                let start = commands.iter().rev().find(|(s, _)| *s < cut).unwrap().0;
                assert_eq!(e.offset(), Some(start as u64), "cut {cut}: {e}");
                assert!(e.to_string().contains("truncated"), "cut {cut}: {e}");
            }
        }
    }
}

#[test]
fn truncated_binary_command_names_the_byte_and_what_was_announced() {
    let bytes = bytes_of("s_Cylinder_ex.cli");
    // First polyline at byte 230: 81 00, id, dir, n=69, then 276 bytes of points.
    assert_eq!(&bytes[230..232], &[0x81, 0x00]);
    let e = vectors::read_bytes(&bytes[..300], "s_Cylinder_ex.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "s_Cylinder_ex.cli: byte 230: truncated $$POLYLINE (command 129): 2n=138 16-bit values announced, 62 bytes left"
    );
    let e = vectors::read_bytes(&bytes[..235], "s_Cylinder_ex.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "s_Cylinder_ex.cli: byte 230: truncated $$POLYLINE (command 129): 6 bytes of u16 id, dir and n expected, 3 bytes left"
    );
    let e = vectors::read_bytes(&bytes[..231], "s_Cylinder_ex.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "s_Cylinder_ex.cli: byte 230: truncated command id: 2 bytes expected, 1 byte left"
    );
}

fn binary_header() -> Vec<u8> {
    b"$$HEADERSTART\n$$BINARY\n$$UNITS/1\n$$LAYERS/1\n$$HEADEREND".to_vec()
}

#[test]
fn count_larger_than_the_data_is_an_error_not_an_allocation() {
    // Binary hatches long announcing 100 segments with 96 bytes of data.
    let mut b = binary_header();
    let start = b.len();
    b.extend(127u16.to_le_bytes());
    b.extend(1.5f32.to_le_bytes());
    let cmd = b.len();
    b.extend(132u16.to_le_bytes());
    b.extend(1i32.to_le_bytes());
    b.extend(100i32.to_le_bytes());
    b.extend([0u8; 96]);
    let e = vectors::read_bytes(&b, "x.cli").unwrap_err();
    assert_eq!(cmd, start + 6);
    assert_eq!(
        e.to_string(),
        format!("x.cli: byte {cmd}: truncated $$HATCHES (command 132): 4n=400 f32 values announced, 96 bytes left")
    );

    // A polyline long announcing i32::MAX points: refused before any allocation.
    let mut b = binary_header();
    b.extend(127u16.to_le_bytes());
    b.extend(0f32.to_le_bytes());
    let cmd = b.len();
    b.extend(130u16.to_le_bytes());
    b.extend(1i32.to_le_bytes());
    b.extend(0i32.to_le_bytes());
    b.extend(i32::MAX.to_le_bytes());
    b.extend([0u8; 16]);
    let e = vectors::read_bytes(&b, "x.cli").unwrap_err();
    assert_eq!(e.offset(), Some(cmd as u64));
    assert!(
        e.to_string()
            .contains("2n=4294967294 f32 values announced, 16 bytes left"),
        "{e}"
    );

    // A negative count.
    let len = b.len();
    b[len - 20..len - 16].copy_from_slice(&(-3i32).to_le_bytes());
    let e = vectors::read_bytes(&b, "x.cli").unwrap_err();
    assert!(e.to_string().contains("negative count -3"), "{e}");

    // The real file with the first polyline's n patched to 65535.
    let mut bytes = bytes_of("s_Cylinder_ex.cli");
    bytes[236..238].copy_from_slice(&u16::MAX.to_le_bytes());
    let left = bytes.len() - 238;
    let e = vectors::read_bytes(&bytes, "s_Cylinder_ex.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        format!("s_Cylinder_ex.cli: byte 230: truncated $$POLYLINE (command 129): 2n=131070 16-bit values announced, {left} bytes left")
    );

    // ASCII: 5 points announced, 3 given before the next command.
    let text = "$$HEADERSTART\n$$ASCII\n$$UNITS/1\n$$HEADEREND\n$$GEOMETRYSTART\n$$LAYER/1\n$$POLYLINE/1,1,5,0,0,1,1,\n2,2\n$$LAYER/2\n";
    let e = vectors::read_bytes(text.as_bytes(), "a.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "a.cli: line 9: expected a number in $$POLYLINE (5 points announced, 3 read), found '$$LAYER'"
    );
    // ASCII: an absurd count at the end of the file.
    let text =
        "$$HEADERSTART\n$$ASCII\n$$HEADEREND\n$$LAYER/1\n$$HATCHES/1,999999999999999999,1,2,3,4";
    let t = Instant::now();
    let e = vectors::read_bytes(text.as_bytes(), "a.cli").unwrap_err();
    assert!(t.elapsed().as_secs_f64() < 1.0);
    assert_eq!(
        e.to_string(),
        "a.cli: line 5: expected a number in $$HATCHES (999999999999999999 hatches announced, 1 read), found end of file"
    );
}

#[test]
fn non_numeric_field_names_the_line() {
    let text = String::from_utf8(bytes_of("frustrum_ASCII.cli")).unwrap();
    let broken = text.replacen("3984.00122", "abc", 1);
    let e = vectors::read_bytes(broken.as_bytes(), "frustrum_ASCII.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "frustrum_ASCII.cli: line 12: expected a number in $$POLYLINE, found 'abc'"
    );
    // The same through the streaming reader and the index.
    let tmp = TempFile::new("nonnumeric");
    std::fs::write(&tmp.0, broken.as_bytes()).unwrap();
    let mut reader = LayerReader::open(&tmp.0).unwrap();
    let e = reader.next_layer().unwrap_err();
    assert_eq!(e.line(), Some(12));
    let index = LayerIndex::build(&tmp.0).unwrap();
    assert_eq!(index.read_layer(0).unwrap_err().line(), Some(12));

    // In a hatch on a later line, and in the header.
    let broken = text.replacen("$$LAYER/40.0", "$$LAYER/4x0", 1);
    let e = vectors::read_bytes(broken.as_bytes(), "f.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "f.cli: line 14: expected a number in $$LAYER, found '4x0'"
    );
    let broken = text.replacen("$$UNITS/00000000.005000", "$$UNITS/five", 1);
    let e = vectors::read_bytes(broken.as_bytes(), "f.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "f.cli: line 3: expected a positive number in $$UNITS, found 'five'"
    );
    let broken = text.replacen("$$LAYERS/000100", "$$LAYERS/-1", 1);
    let e = vectors::read_bytes(broken.as_bytes(), "f.cli").unwrap_err();
    assert_eq!(e.line(), Some(8), "{e}");
    let broken = text.replacen("$$POLYLINE/1,1,23", "$$POLYLINE/1,7,23", 1);
    let e = vectors::read_bytes(broken.as_bytes(), "f.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "f.cli: line 12: expected a direction (0, 1 or 2) in $$POLYLINE, found '7'"
    );
}

#[test]
fn unknown_command_is_an_error_with_its_position() {
    let mut bytes = bytes_of("s_Cylinder_ex.cli");
    bytes[230] = 0x99;
    let e = vectors::read_bytes(&bytes, "s_Cylinder_ex.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "s_Cylinder_ex.cli: byte 230: unknown command id 153 (expected 127 to 132)"
    );
    // Later in the file, through the streaming reader.
    let (_, commands) = cylinder_commands(&bytes_of("s_Cylinder_ex.cli"));
    let (at, _) = commands[100];
    let mut bytes = bytes_of("s_Cylinder_ex.cli");
    bytes[at..at + 2].copy_from_slice(&7u16.to_le_bytes());
    let tmp = TempFile::new("unknown");
    std::fs::write(&tmp.0, &bytes).unwrap();
    let e = LayerReader::open(&tmp.0)
        .unwrap()
        .find_map(Result::err)
        .unwrap();
    assert_eq!(e.offset(), Some(at as u64), "{e}");
    let e = LayerIndex::build(&tmp.0).unwrap_err();
    assert_eq!(e.offset(), Some(at as u64), "{e}");

    let text = "$$HEADERSTART\n$$ASCII\n$$HEADEREND\n$$LAYER/1\n$$ARC/1,2,3\n";
    let e = vectors::read_bytes(text.as_bytes(), "a.cli").unwrap_err();
    assert_eq!(e.line(), Some(5));
    assert!(e.to_string().contains("unknown command '$$ARC'"), "{e}");
}

#[test]
fn missing_header_end_is_an_error() {
    let text = String::from_utf8(bytes_of("frustrum_ASCII.cli")).unwrap();
    let broken = text.replacen("$$HEADEREND\n", "", 1);
    let e = vectors::read_bytes(broken.as_bytes(), "frustrum_ASCII.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "frustrum_ASCII.cli: line 9: expected $$HEADEREND before '$$GEOMETRYSTART'"
    );
    let e = vectors::read_bytes(b"$$HEADERSTART\r\n$$ASCII\r\n$$UNITS/1\r\n", "h.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "h.cli: line 4: missing $$HEADEREND: the file ends inside the header"
    );
    // Binary: the geometry starts where $$HEADEREND should be.
    let bytes = bytes_of("s_Cylinder_ex.cli");
    let at = bytes.windows(11).position(|w| w == b"$$HEADEREND").unwrap();
    let mut broken = bytes[..at].to_vec();
    broken.extend(&bytes[at + 11..]);
    let e = vectors::read_bytes(&broken, "s_Cylinder_ex.cli").unwrap_err();
    assert_eq!(e.line(), Some(9), "{e}");
    assert!(
        e.to_string()
            .contains("expected a header command starting with '$$'"),
        "{e}"
    );
    // Other broken headers.
    let e = vectors::read_bytes(b"", "e.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "e.cli: line 1: expected $$HEADERSTART, found end of file"
    );
    let e = vectors::read_bytes(b"$$HEADERSTART\n$$UNITS/1\n$$HEADEREND\n", "e.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "e.cli: line 3: expected $$ASCII or $$BINARY in the header"
    );
    let e = vectors::read_bytes(
        b"$$HEADERSTART\n$$ASCII\n// open comment\n$$HEADEREND\n",
        "e.cli",
    )
    .unwrap_err();
    assert_eq!(e.line(), Some(3), "{e}");
}

#[test]
fn geometry_before_the_first_layer_is_an_error() {
    let text = "$$HEADERSTART\n$$ASCII\n$$HEADEREND\n$$GEOMETRYSTART\n$$POLYLINE/1,1,2,0,0,1,1\n";
    let e = vectors::read_bytes(text.as_bytes(), "a.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        "a.cli: line 5: expected $$LAYER before $$POLYLINE"
    );
    let mut b = binary_header();
    let at = b.len();
    b.extend(131u16.to_le_bytes());
    b.extend([1, 0, 0, 0]);
    let e = vectors::read_bytes(&b, "b.cli").unwrap_err();
    assert_eq!(
        e.to_string(),
        format!("b.cli: byte {at}: expected a layer command (127 or 128) before $$HATCHES (command 131)")
    );
}

// ---------------------------------------------------------------------------------------------
// What real files do

#[test]
fn tolerates_crlf_padding_integer_z_comments_missing_geometry_start_and_trailing_bytes() {
    let text = "\u{feff}$$HEADERSTART\r\n\
        // a comment\r\n spanning lines //\r\n\
        $$ASCII\r\n\
        $$UNITS/00000000.010000 // hundredths //\r\n\
        $$VERSION/200\r\n\
        $$LABEL/3,left part\r\n\
        $$LABEL/4,right, with comma\r\n\
        $$DATE/020724\r\n\
        $$DIMENSION/-0000001.000000,-0000002.000000,00000000.100000,00000003.000000,00000004.000000,00000000.200000\r\n\
        $$LAYERS/000004\r\n\
        $$ALIGN\r\n\
        $$USERDATA/acme,12,ab\n$$HEADER\r\n\
        $$HEADEREND\r\n\
        $$LAYER/10\r\n\
        $$POLYLINE/3,0,3,-100,-200,0300,\r\n  400 , -100\t-200\r\n\
        $$LAYER/015\r\n\
        $$LAYER/20.0\r\n\
        // comment between\r\n commands //\r\n\
        $$POWER/250\r\n\
        $$HATCHES/4,1,1.5,2.5,3.5,4.5\r\n\
        $$LAYER/30\r\n\
        $$GEOMETRYEND\r\n\
        trailing garbage \0\x01\x02";
    let f = vectors::read_bytes(text.as_bytes(), "t.cli").unwrap_or_else(|e| panic!("{e}"));
    let h = &f.header;
    assert_eq!(h.units_mm, 0.01);
    assert_eq!(
        h.labels,
        vec![(3, "left part".into()), (4, "right, with comma".into())]
    );
    assert_eq!(h.dimension_mm, Some([-1.0, -2.0, 0.1, 3.0, 4.0, 0.2]));
    assert_eq!(h.layers_declared, Some(4));
    assert!(h.aligned);
    assert_eq!(
        h.user_data,
        vec![("acme".to_string(), b"ab\n$$HEADER\r".to_vec())]
    );
    assert_eq!(f.layers.len(), 4);
    let near = |a: &[f64], b: &[f64]| {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(*x, *y, 1e-12))
    };
    let z: Vec<f64> = f.layers.iter().map(|l| l.z_mm).collect();
    assert!(near(&z, &[0.1, 0.15, 0.2, 0.3]), "{z:?}");
    let p = &f.layers[0].polylines[0];
    assert_eq!((p.part, p.direction), (3, Direction::Clockwise));
    let flat: Vec<f64> = p.points.iter().flatten().copied().collect();
    assert!(near(&flat, &[-1.0, -2.0, 3.0, 4.0, -1.0, -2.0]), "{flat:?}");
    assert!(f.layers[1].is_empty() && f.layers[3].is_empty());
    assert_eq!(f.layers[2].parameters, vec![MarkingParameter::Power(250.0)]);
    assert_eq!(f.layers[2].hatches[0].segments.len(), 1);
    assert!(near(
        &f.layers[2].hatches[0].segments[0],
        &[0.015, 0.025, 0.035, 0.045]
    ));
    let info = Info::of(&f);
    assert_eq!(info.parts.len(), 2);
    assert_eq!(info.parts[1].label, "right, with comma");
    assert!(near(
        &info.parts[1].bbox.unwrap(),
        &[0.015, 0.025, 0.035, 0.045]
    ));

    // The same content as a file, streamed and indexed (line numbers continue past USERDATA).
    let tmp = TempFile::new("tolerant");
    std::fs::write(&tmp.0, text.as_bytes()).unwrap();
    check_stream_and_index(&tmp.0);
    let broken = text.replacen("$$LAYER/30", "$$LAYER/3o", 1);
    let e = vectors::read_bytes(broken.as_bytes(), "t.cli").unwrap_err();
    assert_eq!(e.line(), Some(25), "{e}");
}

#[test]
fn binary_mixes_short_and_long_commands_and_tolerates_a_line_break_after_the_header() {
    let mut b =
        b"$$HEADERSTART\r\n$$BINARY\r\n$$UNITS/0.5\r\n$$LABEL/2,b\r\n$$HEADEREND\r\n".to_vec();
    b.extend(128u16.to_le_bytes());
    b.extend(4u16.to_le_bytes());
    b.extend(129u16.to_le_bytes());
    for v in [2u16, 1, 2] {
        b.extend(v.to_le_bytes());
    }
    for v in [-3i16, -4, 5, 6] {
        b.extend(v.to_le_bytes());
    }
    b.extend(127u16.to_le_bytes());
    b.extend(5.5f32.to_le_bytes());
    b.extend(131u16.to_le_bytes());
    b.extend(2u16.to_le_bytes());
    b.extend(1u16.to_le_bytes());
    for v in [-1i16, 1, -32768, 32767] {
        b.extend(v.to_le_bytes());
    }
    b.extend(130u16.to_le_bytes());
    for v in [2i32, 2, 1] {
        b.extend(v.to_le_bytes());
    }
    b.extend(1.25f32.to_le_bytes());
    b.extend((-2.5f32).to_le_bytes());
    b.extend(132u16.to_le_bytes());
    b.extend(2i32.to_le_bytes());
    b.extend(0i32.to_le_bytes());
    b.extend(b"$$GEOMETRYEND\r\nwhatever follows");
    let f = vectors::read_bytes(&b, "m.cli").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.layers.len(), 2);
    assert_eq!(f.layers[0].z_mm, 2.0);
    assert_eq!(
        f.layers[0].polylines[0].points,
        vec![[-1.5, -2.0], [2.5, 3.0]]
    );
    assert_eq!(f.layers[1].z_mm, 2.75);
    assert_eq!(
        f.layers[1].hatches[0].segments,
        vec![[-0.5, 0.5, -16384.0, 16383.5]]
    );
    assert_eq!(f.layers[1].polylines[0].direction, Direction::Open);
    assert_eq!(f.layers[1].polylines[0].points, vec![[0.625, -1.25]]);
    assert!(f.layers[1].hatches[1].segments.is_empty());
}

#[test]
fn info_json_and_display() {
    let path = shared_cli("s_Cylinder_ex.cli");
    let info = vectors::info(&path).unwrap();
    let v: serde_json::Value = serde_json::from_str(&info.to_json()).unwrap();
    for key in VECTORS_INFO_KEYS {
        assert!(v.get(key).is_some(), "missing key {key}");
    }
    assert_eq!(v["format"], "binary");
    assert_eq!(v["layers"], 8);
    assert_eq!(v["units"], 0.01);
    assert_eq!(v["layer_thickness"], 0.15);
    assert_eq!(v["polylines"], 233);
    assert_eq!(v["parts"][0]["id"], 1);
    assert_eq!(v["parts"][0]["label"], "part1");
    assert_eq!(v["parts"][0]["bbox"].as_array().unwrap().len(), 4);
    assert_eq!(v["declared_dimension_mm"][0], -4.9387);
    let text = info.to_string();
    assert!(text.lines().count() >= 5, "{text}");
    assert!(text.contains("layers: 8 (declared 8)"), "{text}");

    let ascii = vectors::info(&shared_cli("frustrum_ASCII.cli")).unwrap();
    assert_eq!(serde_json::to_value(&ascii).unwrap()["format"], "ascii");

    // A part without $$LABEL gets "".
    let text =
        "$$HEADERSTART\n$$ASCII\n$$LABEL/1,one\n$$HEADEREND\n$$LAYER/1\n$$POLYLINE/7,2,2,0,0,1,1\n";
    let f = vectors::read_bytes(text.as_bytes(), "p.cli").unwrap();
    let info = Info::of(&f);
    assert_eq!(info.parts.len(), 2);
    assert_eq!(
        (
            info.parts[0].id,
            info.parts[0].label.as_str(),
            info.parts[0].bbox
        ),
        (1, "one", None)
    );
    assert_eq!((info.parts[1].id, info.parts[1].label.as_str()), (7, ""));
    assert_eq!(info.parts[1].bbox, Some([0.0, 0.0, 1.0, 1.0]));
}

#[test]
fn io_errors_name_the_file() {
    let e = vectors::read(Path::new("/nonexistent/dir/missing.cli")).unwrap_err();
    assert!(e.to_string().starts_with("missing.cli: "), "{e}");
    assert!(LayerReader::open(Path::new("/nonexistent/missing.cli")).is_err());
    assert!(LayerIndex::build(Path::new("/nonexistent/missing.cli")).is_err());
    assert!(vectors::info(Path::new("/nonexistent/missing.cli")).is_err());
}

#[test]
fn writers_refuse_what_the_format_cannot_hold() {
    let mut f = synth::generate(1, 2, 4);
    f.layers[0].polylines[0].points[0][0] = f64::NAN;
    assert!(vectors::write_ascii(&f, &mut Vec::new()).is_err());
    assert!(vectors::write_binary(&f, &mut Vec::new()).is_err());
    let mut f = synth::generate(1, 2, 4);
    f.layers[0].polylines[0].part = i64::MAX;
    assert!(vectors::write_binary(&f, &mut Vec::new()).is_err());
    assert!(vectors::write_ascii(&f, &mut Vec::new()).is_ok());
    let mut f = synth::generate(1, 2, 4);
    f.header.units_mm = 0.0;
    assert!(vectors::write_ascii(&f, &mut Vec::new()).is_err());
}

// ---------------------------------------------------------------------------------------------
// Robustness: mutated real files never panic

#[test]
fn mutated_and_cut_files_never_panic() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for name in FILES {
        let bytes = bytes_of(name);
        // Cuts across the ASCII files (every cut of the binary one is tested above).
        for cut in (0..bytes.len()).step_by(997) {
            if let Err(e) = vectors::read_bytes(&bytes[..cut], name) {
                assert!(e.line().is_some() || e.offset().is_some(), "{e}");
            }
        }
        for round in 0..120 {
            let mut m = bytes.clone();
            for _ in 0..1 + round % 4 {
                let at = rng.below(m.len());
                match rng.below(4) {
                    0 => m[at] = rng.next() as u8,
                    1 => m[at] ^= 1 << rng.below(8),
                    2 => {
                        m.remove(at);
                    }
                    _ => m.insert(at, [b'$', b',', b'\n', b'-', 0x84, 0xff][rng.below(6)]),
                }
            }
            if let Ok(f) = vectors::read_bytes(&m, name) {
                // Whatever reads must write and read back.
                let back = vectors::read_bytes(&ascii_bytes(&f), name)
                    .unwrap_or_else(|e| panic!("round {round}: {e}"));
                assert_eq!(back.layers.len(), f.layers.len());
            }
        }
    }
    for _ in 0..500 {
        let len = rng.below(64);
        let mut m = b"$$HEADERSTART\n$$BINARY\n$$HEADEREND".to_vec();
        m.extend((0..len).map(|_| [127u8, 128, 129, 130, 131, 132, 0, 0xff][rng.below(8)]));
        let _ = vectors::read_bytes(&m, "random");
    }
}

// ---------------------------------------------------------------------------------------------
// Throughput (run with: cargo test --release -- --ignored --nocapture)

fn time<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = Instant::now();
    let r = f();
    (r, t.elapsed().as_secs_f64())
}

fn report(what: &str, bytes: u64, secs: f64) {
    println!(
        "{what:<40} {:>8.1} MB in {secs:>6.3} s = {:>7.1} MB/s",
        bytes as f64 / 1e6,
        bytes as f64 / 1e6 / secs
    );
}

fn measure(
    tag: &str,
    f: &VectorFile,
    write: fn(&VectorFile, &mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) {
    let tmp = TempFile::new(tag);
    let (_, secs) = time(|| {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp.0).unwrap());
        write(f, &mut w).unwrap();
    });
    let bytes = std::fs::metadata(&tmp.0).unwrap().len();
    report(&format!("{tag}: write"), bytes, secs);
    let (back, secs) = time(|| vectors::read(&tmp.0).unwrap());
    report(&format!("{tag}: read()"), bytes, secs);
    assert_eq!(back.layers.len(), f.layers.len());
    drop(back);
    let (n, secs) = time(|| {
        let mut n = 0usize;
        let mut r = LayerReader::open(&tmp.0).unwrap();
        while let Some(l) = r.next_layer().unwrap() {
            n += l.hatches.iter().map(|h| h.segments.len()).sum::<usize>();
        }
        n
    });
    report(&format!("{tag}: LayerReader"), bytes, secs);
    assert_eq!(
        n,
        f.layers
            .iter()
            .map(|l| l.hatches[0].segments.len())
            .sum::<usize>()
    );
    let (index, secs) = time(|| LayerIndex::build(&tmp.0).unwrap());
    report(&format!("{tag}: LayerIndex::build"), bytes, secs);
    let (_, secs) = time(|| index.read_layer(index.len() / 2).unwrap());
    println!("{tag}: read_layer(middle) in {:.2} ms", secs * 1e3);
    let (info, secs) = time(|| vectors::info(&tmp.0).unwrap());
    report(&format!("{tag}: info()"), bytes, secs);
    assert_eq!(info.layers, f.layers.len());
}

#[test]
#[ignore = "throughput measurement; run in release"]
fn throughput_on_100_mb_files() {
    // ~100 MB each: ASCII takes ~70 bytes per hatch segment, binary 16.
    let ascii = synth::generate(200, 10_000, 256);
    measure("ascii", &ascii, vectors::write_ascii);
    drop(ascii);
    let binary = synth::generate(620, 10_000, 256);
    measure("binary", &binary, vectors::write_binary);
}

#[test]
#[ignore = "allocates about 400 MB"]
fn generator_makes_ten_million_hatch_segments() {
    let (f, secs) = time(|| synth::generate(1000, 10_000, 64));
    println!("generated 1,000 layers with 10^7 hatch segments in {secs:.2} s");
    assert_eq!(Info::of(&f).hatches, 10_000_000);
    assert_eq!(f.layers.len(), 1000);
}

#[test]
fn units_that_would_overflow_coordinates_are_refused() {
    for units in ["1e308", "1e-300", "inf"] {
        let text = format!(
            "$$HEADERSTART\n$$ASCII\n$$UNITS/{units}\n$$HEADEREND\n$$GEOMETRYSTART\n$$LAYER/1\n$$POLYLINE/1,1,2,0,0,1,1\n"
        );
        let err = vectors::read_bytes(text.as_bytes(), "u.cli")
            .expect_err(units)
            .to_string();
        assert!(
            err.starts_with("u.cli: line 3:") && err.contains("$$UNITS"),
            "{err}"
        );
    }
}
