//! A plain little-endian binary encoding for training checkpoints: exact bits of every float
//! (so a resumed run continues bit for bit), tagged sections so a mismatched reader fails with
//! a clear message instead of misreading.

/// Appends values to a byte buffer.
#[derive(Default)]
pub struct StateWriter {
    buf: Vec<u8>,
}

impl StateWriter {
    /// An empty writer.
    pub fn new() -> Self {
        Self::default()
    }
    /// A section tag (checked by [`StateReader::tag`]).
    pub fn tag(&mut self, t: &str) {
        self.str(t);
    }
    /// A `u64`.
    pub fn u64(&mut self, v: u64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// A `u32`.
    pub fn u32(&mut self, v: u32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// An `f64` (its bits).
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    /// A `bool`.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(v as u8);
    }
    /// A string.
    pub fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.buf.extend_from_slice(s.as_bytes());
    }
    /// A slice of `f32` (their bits).
    pub fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        self.buf.reserve(v.len() * 4);
        for x in v {
            self.buf.extend_from_slice(&x.to_le_bytes());
        }
    }
    /// A slice of `u32`.
    pub fn u32s(&mut self, v: &[u32]) {
        self.u64(v.len() as u64);
        for x in v {
            self.buf.extend_from_slice(&x.to_le_bytes());
        }
    }
    /// A slice of `u8`.
    pub fn bytes(&mut self, v: &[u8]) {
        self.u64(v.len() as u64);
        self.buf.extend_from_slice(v);
    }
    /// A list of `usize` (as `u64`).
    pub fn usizes(&mut self, v: &[usize]) {
        self.u64(v.len() as u64);
        for &x in v {
            self.u64(x as u64);
        }
    }
    /// The encoded bytes.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

/// Why a checkpoint could not be read.
#[derive(Debug, thiserror::Error)]
#[error("checkpoint: {0}")]
pub struct StateError(pub String);

/// Reads what a [`StateWriter`] wrote, in the same order.
pub struct StateReader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> StateReader<'a> {
    /// A reader over `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        StateReader { buf, pos: 0 }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], StateError> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.buf.len())
            .ok_or_else(|| StateError(format!("truncated at byte {}", self.pos)))?;
        let s = &self.buf[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    /// Checks the next section tag is `t`.
    pub fn tag(&mut self, t: &str) -> Result<(), StateError> {
        let got = self.str()?;
        if got == t {
            Ok(())
        } else {
            Err(StateError(format!("expected section `{t}`, found `{got}`")))
        }
    }
    /// A `u64`.
    pub fn u64(&mut self) -> Result<u64, StateError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8")))
    }
    /// A `u32`.
    pub fn u32(&mut self) -> Result<u32, StateError> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4")))
    }
    /// An `f64`.
    pub fn f64(&mut self) -> Result<f64, StateError> {
        Ok(f64::from_bits(self.u64()?))
    }
    /// A `bool`.
    pub fn bool(&mut self) -> Result<bool, StateError> {
        Ok(self.take(1)?[0] != 0)
    }
    fn len(&mut self, elem: usize) -> Result<usize, StateError> {
        let n = self.u64()?;
        let n = usize::try_from(n).map_err(|_| StateError(format!("bad length {n}")))?;
        if n.saturating_mul(elem) > self.buf.len() - self.pos {
            return Err(StateError(format!("length {n} runs past the end")));
        }
        Ok(n)
    }
    /// A string.
    pub fn str(&mut self) -> Result<String, StateError> {
        let n = self.len(1)?;
        String::from_utf8(self.take(n)?.to_vec()).map_err(|e| StateError(e.to_string()))
    }
    /// A list of `f32`.
    pub fn f32s(&mut self) -> Result<Vec<f32>, StateError> {
        let n = self.len(4)?;
        Ok(self
            .take(n * 4)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4")))
            .collect())
    }
    /// A list of `u32`.
    pub fn u32s(&mut self) -> Result<Vec<u32>, StateError> {
        let n = self.len(4)?;
        Ok(self
            .take(n * 4)?
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().expect("4")))
            .collect())
    }
    /// A list of `u8`.
    pub fn bytes(&mut self) -> Result<Vec<u8>, StateError> {
        let n = self.len(1)?;
        Ok(self.take(n)?.to_vec())
    }
    /// A list of `usize`.
    pub fn usizes(&mut self) -> Result<Vec<usize>, StateError> {
        let n = self.len(8)?;
        (0..n).map(|_| Ok(self.u64()? as usize)).collect()
    }
    /// Checks everything was read.
    pub fn end(&self) -> Result<(), StateError> {
        if self.pos == self.buf.len() {
            Ok(())
        } else {
            Err(StateError(format!(
                "{} unread bytes at the end",
                self.buf.len() - self.pos
            )))
        }
    }
}

/// Appends a training curve, every float bit for bit.
pub fn write_curve(w: &mut StateWriter, c: &crate::artifacts::TrainingCurve) {
    w.tag("curve");
    w.str(&c.label);
    w.u64(c.points.len() as u64);
    for p in &c.points {
        write_point(w, p);
    }
}

/// The curve [`write_curve`] wrote.
pub fn read_curve(r: &mut StateReader<'_>) -> Result<crate::artifacts::TrainingCurve, StateError> {
    r.tag("curve")?;
    let label = r.str()?;
    let n = r.u64()?;
    let points = (0..n).map(|_| read_point(r)).collect::<Result<_, _>>()?;
    Ok(crate::artifacts::TrainingCurve { label, points })
}

fn write_opt(w: &mut StateWriter, v: Option<f64>) {
    w.bool(v.is_some());
    w.f64(v.unwrap_or(0.0));
}

fn read_opt(r: &mut StateReader<'_>) -> Result<Option<f64>, StateError> {
    let some = r.bool()?;
    let v = r.f64()?;
    Ok(some.then_some(v))
}

/// Appends one evaluation of a curve.
pub fn write_point(w: &mut StateWriter, p: &crate::artifacts::CurvePoint) {
    w.u64(p.step);
    w.f64(p.psnr);
    w.f64(p.ssim);
    write_opt(w, p.lpips);
    w.f64(p.mse);
    write_opt(w, p.avg_error);
    w.u64(p.primitives);
    w.f64(p.seconds);
    w.f64(p.loss);
}

/// The evaluation [`write_point`] wrote.
pub fn read_point(r: &mut StateReader<'_>) -> Result<crate::artifacts::CurvePoint, StateError> {
    Ok(crate::artifacts::CurvePoint {
        step: r.u64()?,
        psnr: r.f64()?,
        ssim: r.f64()?,
        lpips: read_opt(r)?,
        mse: r.f64()?,
        avg_error: read_opt(r)?,
        primitives: r.u64()?,
        seconds: r.f64()?,
        loss: r.f64()?,
    })
}

/// Flattens `[[f32; K]]` to its values.
pub fn flat<const K: usize>(v: &[[f32; K]]) -> Vec<f32> {
    v.iter().flatten().copied().collect()
}

/// Regroups values into `[f32; K]`s (the length must be a multiple of `K`).
pub fn unflat<const K: usize>(v: &[f32]) -> Result<Vec<[f32; K]>, StateError> {
    if !v.len().is_multiple_of(K) {
        return Err(StateError(format!(
            "{} values are not groups of {K}",
            v.len()
        )));
    }
    Ok(v.chunks_exact(K)
        .map(|c| c.try_into().expect("K"))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_round_trip_bit_for_bit() {
        let mut w = StateWriter::new();
        w.tag("t");
        w.u64(7);
        w.f64(-0.0);
        w.f32s(&[1.5, f32::NAN, f32::MIN_POSITIVE / 3.0]);
        w.usizes(&[3, 1]);
        w.bool(true);
        w.bytes(&[1, 2]);
        let b = w.finish();
        let mut r = StateReader::new(&b);
        r.tag("t").unwrap();
        assert_eq!(r.u64().unwrap(), 7);
        assert_eq!(r.f64().unwrap().to_bits(), (-0.0f64).to_bits());
        let f = r.f32s().unwrap();
        assert_eq!(f[0], 1.5);
        assert!(f[1].is_nan());
        assert_eq!(f[2].to_bits(), (f32::MIN_POSITIVE / 3.0).to_bits());
        assert_eq!(r.usizes().unwrap(), vec![3, 1]);
        assert!(r.bool().unwrap());
        assert_eq!(r.bytes().unwrap(), vec![1, 2]);
        r.end().unwrap();
    }

    #[test]
    fn a_wrong_or_truncated_checkpoint_is_an_error() {
        let mut w = StateWriter::new();
        w.tag("a");
        w.f32s(&[1.0; 10]);
        let b = w.finish();
        assert!(StateReader::new(&b).tag("b").unwrap_err().0.contains("`a`"));
        let mut r = StateReader::new(&b[..b.len() - 3]);
        r.tag("a").unwrap();
        assert!(r.f32s().is_err());
    }
}
