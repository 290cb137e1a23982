//! Frame sizes as users type them.

/// Parses `WxH` (e.g. `640x480`) into (width, height), both positive.
pub fn parse_size(text: &str) -> Result<(usize, usize), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("`{text}` is not WxH (e.g. 640x480)"))?;
    let parse = |s: &str| s.trim().parse::<usize>().ok().filter(|&v| v > 0);
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!(
            "`{text}` is not WxH with positive integers (e.g. 640x480)"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert_eq!(parse_size(" 8 X 4"), Ok((8, 4)));
        assert!(parse_size("640").is_err());
        assert!(parse_size("0x4").is_err());
    }
}
