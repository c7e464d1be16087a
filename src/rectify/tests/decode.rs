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
