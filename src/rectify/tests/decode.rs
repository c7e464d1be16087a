//! Decoding JPEGs, luma, and rectifying each pixel format of a `DynamicImage`.

use image::{DynamicImage, ImageBuffer, Luma, Rgb, RgbImage};

use super::*;

#[test]
fn dynamic_dispatch_keeps_the_nearest_format() {
    let r = Rectifier::new(
        &camera_of(identity_h(20.0), None),
        grid_1mm(30.0, 20.0),
        Interpolation::Bilinear,
        0,
    )
    .unwrap();
    let rgba = DynamicImage::ImageRgba8(image::RgbaImage::from_pixel(
        30,
        20,
        image::Rgba([1, 2, 3, 4]),
    ));
    let out = r.rectify_dynamic(&rgba);
    assert_eq!(out.as_rgb8().unwrap().get_pixel(3, 3).0, [1, 2, 3]);
    let la = DynamicImage::ImageLumaA8(image::GrayAlphaImage::from_pixel(
        30,
        20,
        image::LumaA([9, 0]),
    ));
    assert_eq!(
        r.rectify_dynamic(&la).as_luma8().unwrap().get_pixel(0, 0)[0],
        9
    );
    let l16 = DynamicImage::ImageLuma16(ImageBuffer::from_pixel(30, 20, Luma([60000u16])));
    assert_eq!(
        r.rectify_dynamic(&l16).as_luma16().unwrap().get_pixel(5, 5)[0],
        60000
    );
    let f = DynamicImage::ImageRgb32F(image::Rgb32FImage::from_pixel(30, 20, Rgb([1.0, 0.5, 0.0])));
    assert_eq!(
        r.rectify_dynamic(&f).as_rgb16().unwrap().get_pixel(5, 5).0,
        [65535, 32768, 0]
    );
}

fn encode_jpeg(img: &DynamicImage) -> Vec<u8> {
    let mut buf = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, 92);
    img.write_with_encoder(enc).unwrap();
    buf
}

#[test]
fn decode_jpeg_rgb_and_grey() {
    let rgb = RgbImage::from_fn(97, 61, |x, y| {
        Rgb([0, 1, 2].map(|c| (smooth(x as usize, y as usize, c) * 255.0) as u8))
    });
    let gray = luma(&rgb);
    let d = decode_jpeg(&encode_jpeg(&DynamicImage::ImageRgb8(rgb.clone()))).unwrap();
    let d = d.as_rgb8().expect("colour JPEG decodes to RGB8");
    assert_eq!(d.dimensions(), (97, 61));
    let mad = d
        .as_raw()
        .iter()
        .zip(rgb.as_raw())
        .map(|(a, b)| f64::from(a.abs_diff(*b)))
        .sum::<f64>()
        / d.as_raw().len() as f64;
    assert!(mad < 3.0, "mean abs diff {mad}");

    let d = decode_jpeg(&encode_jpeg(&DynamicImage::ImageLuma8(gray.clone()))).unwrap();
    let d = d.as_luma8().expect("grey JPEG decodes to L8");
    assert_eq!(d.dimensions(), (97, 61));
    let mad = d
        .as_raw()
        .iter()
        .zip(gray.as_raw())
        .map(|(a, b)| f64::from(a.abs_diff(*b)))
        .sum::<f64>()
        / d.as_raw().len() as f64;
    assert!(mad < 2.0, "mean abs diff {mad}");
}

#[test]
fn decode_jpeg_rejects_garbage_without_panicking() {
    assert!(decode_jpeg(&[]).is_err());
    assert!(decode_jpeg(b"definitely not a jpeg").is_err());
    let mut rng = Rng(42);
    for len in [1usize, 2, 3, 10, 100, 5000] {
        let junk: Vec<u8> = (0..len).map(|_| (rng.next() >> 56) as u8).collect();
        assert!(decode_jpeg(&junk).is_err());
    }
    // A JPEG header followed by junk, and truncated JPEGs: error or partial
    // image, never a panic.
    let good = encode_jpeg(&DynamicImage::ImageRgb8(RgbImage::from_pixel(
        64,
        64,
        Rgb([10, 200, 30]),
    )));
    for cut in [2usize, 20, 200, good.len() / 2, good.len() - 2] {
        let _ = decode_jpeg(&good[..cut]);
    }
    let mut spoiled = good.clone();
    for b in spoiled.iter_mut().skip(300).step_by(7) {
        *b = (rng.next() >> 56) as u8;
    }
    let _ = decode_jpeg(&spoiled);
}

#[test]
fn a_truncated_jpeg_is_an_error_not_a_grey_picture() {
    let mut rng = Rng(7);
    let noisy = RgbImage::from_fn(128, 96, |_, _| {
        Rgb([(rng.next() >> 56) as u8, (rng.next() >> 56) as u8, 9])
    });
    let good = encode_jpeg(&DynamicImage::ImageRgb8(noisy));
    assert!(decode_jpeg(&good).is_ok() && decode_jpeg_luma(&good).is_ok());
    // Cut in the middle of the entropy-coded data.
    let cut = &good[..good.len() * 2 / 3];
    assert!(
        decode_jpeg(cut).is_err(),
        "a truncated frame must not decode"
    );
    assert!(
        decode_jpeg_luma(cut).is_err(),
        "a truncated frame must not decode"
    );
}

/// What the decoders refuse keeps the decoder's own error as its source, said once in the chain.
#[test]
fn decoder_errors_keep_the_decoders_error_as_their_source() {
    let e = decode_jpeg(b"\xFF\xD8\xFF\xC0 definitely not a jpeg").unwrap_err();
    assert!(matches!(e, RectifyError::JpegData(_)), "{e:?}");
    let cause = std::error::Error::source(&e)
        .expect("the decoder's error")
        .to_string();
    let chain = crate::logging::chain(&e);
    assert_eq!(chain, format!("JPEG decoding failed: {cause}"));
    let e = decode_frame(b"not a picture of any kind").unwrap_err();
    assert!(matches!(e, RectifyError::Image(_)), "{e:?}");
    let cause = std::error::Error::source(&e)
        .expect("the image crate's error")
        .to_string();
    assert_eq!(
        crate::logging::chain(&e),
        format!("cannot read the picture: {cause}")
    );
}

#[test]
fn a_jpeg_header_claiming_65500_squared_pixels_is_refused_before_allocating() {
    let good = encode_jpeg(&DynamicImage::ImageRgb8(RgbImage::from_pixel(
        16,
        16,
        Rgb([1, 2, 3]),
    )));
    // The baseline frame header (SOF0: FF C0, length, precision, height, width).
    let sof = good
        .windows(2)
        .position(|w| w == [0xFF, 0xC0])
        .expect("SOF0");
    let mut bomb = good.clone();
    bomb[sof + 5..sof + 9].copy_from_slice(&[0xFF, 0xDC, 0xFF, 0xDC]);
    for result in [
        decode_jpeg(&bomb).map(|_| ()),
        decode_jpeg_luma(&bomb).map(|_| ()),
    ] {
        let err = result
            .expect_err("65500 x 65500 is no camera frame")
            .to_string();
        assert!(err.contains("65500 x 65500"), "{err}");
    }
}

#[test]
fn luma_is_bt601_rounded() {
    let img = RgbImage::from_fn(256, 3, |x, y| match y {
        0 => Rgb([x as u8, 0, 0]),
        1 => Rgb([0, x as u8, 0]),
        _ => Rgb([x as u8, x as u8, x as u8]),
    });
    let y = luma(&img);
    for x in 0..256u32 {
        let f = f64::from(x);
        assert_eq!(
            u32::from(y.get_pixel(x, 0)[0]),
            (0.299 * f + 0.5).floor() as u32
        );
        assert_eq!(
            u32::from(y.get_pixel(x, 1)[0]),
            (0.587 * f + 0.5).floor() as u32
        );
        assert_eq!(u32::from(y.get_pixel(x, 2)[0]), x);
    }
    let px = luma(&RgbImage::from_pixel(1, 1, Rgb([255, 128, 0])));
    assert_eq!(px.get_pixel(0, 0)[0], 151); // 76.245 + 75.136 = 151.381
}

#[test]
fn frames_smaller_than_the_wide_kernels_window_rectify_like_the_scalar_path() {
    // The AVX-512 RGB kernel reads three rows of 128 bytes from a run's first pixel; a frame
    // smaller than that once passed its bounds check at the frame's first pixel and panicked.
    for (w, h) in [(19u32, 2u32), (40, 1), (1, 1), (21, 3), (60, 2)] {
        let rgb = RgbImage::from_fn(w, h, |x, y| Rgb([0, 1, 2].map(|c| pattern(x, y, c) as u8)));
        let gray = image::GrayImage::from_fn(w, h, |x, y| Luma([pattern(x, y, 0) as u8]));
        let r = Rectifier::new(
            &camera_of(identity_h(f64::from(h)), None),
            grid_1mm(f64::from(w), f64::from(h)),
            Interpolation::Bilinear,
            0,
        )
        .unwrap();
        let [fast, scalar] = both_paths(&r);
        assert_eq!(
            fast.rectify_rgb8(&rgb),
            scalar.rectify_rgb8(&rgb),
            "{w}x{h} RGB"
        );
        assert_eq!(
            fast.rectify_gray8(&gray),
            scalar.rectify_gray8(&gray),
            "{w}x{h} grey"
        );
    }
}

/// A PNG chunk: length, type, data, CRC.
fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let mut crc = flate2::Crc::new();
    crc.update(kind);
    crc.update(data);
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    out.extend_from_slice(&crc.sum().to_be_bytes());
}

#[test]
fn a_picture_its_decoder_panics_on_is_an_error() {
    // A 1 x 1 palette PNG whose palette is 4 bytes long (not a whole colour): the png crate
    // panics on it (found by mutation fuzzing).
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png_chunk(&mut png, b"IHDR", &[0, 0, 0, 1, 0, 0, 0, 1, 8, 3, 0, 0, 0]);
    png_chunk(&mut png, b"PLTE", &[1, 2, 3, 4]);
    let mut idat = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut idat, &[0, 0]).unwrap();
    png_chunk(&mut png, b"IDAT", &idat.finish().unwrap());
    png_chunk(&mut png, b"IEND", &[]);
    for result in [
        decode_frame_luma(&png).map(|_| ()),
        decode_frame(&png).map(|_| ()),
    ] {
        let e = result.expect_err("a damaged picture");
        assert!(e.to_string().contains("the file is damaged"), "{e}");
    }
}
