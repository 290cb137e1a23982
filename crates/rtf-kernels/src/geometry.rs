//! The geometry of a 2-D convolution, as every kernel here takes it.

/// Geometry of a 2-D convolution (symmetric).
#[derive(Debug, Clone, Copy)]
pub struct Geometry {
    pub stride: i64,
    pub padding: i64,
    pub dilation: i64,
    pub groups: i64,
    /// Transposed convolution (never fused by [`crate::onednn`]: callers take the plain path).
    pub transposed: bool,
}

impl Geometry {
    /// A convolution of one group.
    pub const fn ungrouped(stride: i64, padding: i64, dilation: i64, transposed: bool) -> Self {
        Geometry {
            stride,
            padding,
            dilation,
            groups: 1,
            transposed,
        }
    }

    /// A 3×3 convolution's that keeps the size: stride 1, padding 1, no dilation, one group.
    pub const SAME_3X3: Geometry = Geometry {
        stride: 1,
        padding: 1,
        dilation: 1,
        groups: 1,
        transposed: false,
    };
}
