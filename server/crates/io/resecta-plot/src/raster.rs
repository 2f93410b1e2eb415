//! Raster images (e.g. a resectogram) as PNG bytes.

use crate::figure::PlotError;

/// PNG bytes of an 8-bit RGBA image, row-major from the top row.
pub fn rgba_png(width: usize, height: usize, rgba: &[u8]) -> Result<Vec<u8>, PlotError> {
    let want = width * height * 4;
    if width == 0 || height == 0 || rgba.len() != want {
        return Err(PlotError::ImageSize {
            width,
            height,
            want,
            got: rgba.len(),
        });
    }
    let png_err = |e: png::EncodingError| PlotError::Png(e.to_string());
    let (w, h) = (
        u32::try_from(width).map_err(|e| PlotError::Png(e.to_string()))?,
        u32::try_from(height).map_err(|e| PlotError::Png(e.to_string()))?,
    );
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(png_err)?;
    writer.write_image_data(rgba).map_err(png_err)?;
    writer.finish().map_err(png_err)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_through_the_decoder_and_refuses_bad_sizes() {
        let rgba: Vec<u8> = (0..3 * 2 * 4).map(|k| (k * 10) as u8).collect();
        let bytes = rgba_png(3, 2, &rgba).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (3, 2));
        assert_eq!(&buf[..info.buffer_size()], &rgba[..]);
        assert!(matches!(
            rgba_png(3, 3, &rgba),
            Err(PlotError::ImageSize { .. })
        ));
        assert!(matches!(
            rgba_png(0, 2, &[]),
            Err(PlotError::ImageSize { .. })
        ));
    }
}
