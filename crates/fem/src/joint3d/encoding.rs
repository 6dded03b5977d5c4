//! A joint's solution as bytes, for the joint cache ([`JointSolution::to_bytes`],
//! [`JointSolution::from_bytes`]).

use super::*;

/// Version of the byte encoding of [`JointSolution::to_bytes`]; decoding refuses any
/// other.
pub const SOLUTION_ENCODING_VERSION: u64 = 1;

/// Magic bytes that open an encoded [`JointSolution`].
pub(super) const SOLUTION_MAGIC: [u8; 8] = *b"CIJSOL\0\0";

impl JointSolution {
    /// The whole solution as bytes, for a cache: every field, the private stress basis
    /// and its points included, as little-endian `f64` bit patterns and `u64` counts
    /// after an 8-byte magic and [`SOLUTION_ENCODING_VERSION`]. Matrices are stored
    /// column by column. [`JointSolution::from_bytes`] gives back an identical solution.
    pub fn to_bytes(&self) -> Vec<u8> {
        let n = self.stress_basis.len();
        let m = self.stress_points.len();
        let mut out = Vec::with_capacity(8 * (44 + 36 * n + 3 * m) + 256);
        out.extend_from_slice(&SOLUTION_MAGIC);
        let u = |out: &mut Vec<u8>, v: u64| out.extend_from_slice(&v.to_le_bytes());
        u(&mut out, SOLUTION_ENCODING_VERSION);
        let f = |out: &mut Vec<u8>, v: f64| out.extend_from_slice(&v.to_bits().to_le_bytes());
        for v in self.compliance.iter() {
            f(&mut out, *v);
        }
        for v in self.block_compliance.iter() {
            f(&mut out, *v);
        }
        for v in self.block_sections {
            f(&mut out, v);
        }
        f(&mut out, self.asymmetry);
        for v in self.k_bend {
            f(&mut out, v);
        }
        f(&mut out, self.k_axial);
        f(&mut out, self.k_torsion);
        let l = &self.layout;
        for v in [
            l.bottom,
            l.lower_end,
            l.notch_a,
            l.a_end,
            l.b_start,
            l.notch_b,
            l.upper_end,
            l.top,
        ] {
            f(&mut out, v);
        }
        u(&mut out, self.dofs as u64);
        u(&mut out, self.elements as u64);
        f(&mut out, self.residual);
        u(&mut out, n as u64);
        for b in &self.stress_basis {
            for row in b {
                for v in row {
                    f(&mut out, *v);
                }
            }
        }
        u(&mut out, m as u64);
        for p in &self.stress_points {
            for v in p {
                f(&mut out, *v);
            }
        }
        out
    }

    /// Decodes [`JointSolution::to_bytes`]. Refuses (as [`FemError::Invalid`], saying
    /// where) a wrong magic or version, truncated or trailing bytes, and counts that do
    /// not fit the length; the numbers themselves are not checked.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, FemError> {
        let mut r = Reader { bytes, at: 0 };
        if r.take(8)? != SOLUTION_MAGIC {
            return Err(FemError::Invalid(
                "joint solution bytes: wrong magic (not an encoded joint solution)".into(),
            ));
        }
        let version = r.u64()?;
        if version != SOLUTION_ENCODING_VERSION {
            return Err(FemError::Invalid(format!(
                "joint solution bytes: encoding version {version}, expected {SOLUTION_ENCODING_VERSION}"
            )));
        }
        let compliance = Matrix6::from_iterator(r.f64s(36)?);
        let block_compliance = Matrix6::from_iterator(r.f64s(36)?);
        let block_sections = [r.f64()?, r.f64()?];
        let asymmetry = r.f64()?;
        let k_bend = [r.f64()?, r.f64()?];
        let k_axial = r.f64()?;
        let k_torsion = r.f64()?;
        let layout = Layout {
            bottom: r.f64()?,
            lower_end: r.f64()?,
            notch_a: r.f64()?,
            a_end: r.f64()?,
            b_start: r.f64()?,
            notch_b: r.f64()?,
            upper_end: r.f64()?,
            top: r.f64()?,
        };
        let dofs = r.count(0)?;
        let elements = r.count(0)?;
        let residual = r.f64()?;
        let n = r.count(36 * 8)?;
        let mut stress_basis = Vec::with_capacity(n);
        for _ in 0..n {
            let mut b = [[0.0f64; 6]; 6];
            for row in &mut b {
                for v in row.iter_mut() {
                    *v = r.f64()?;
                }
            }
            stress_basis.push(b);
        }
        let m = r.count(3 * 8)?;
        if m != n {
            return Err(FemError::Invalid(format!(
                "joint solution bytes: {m} stress points for {n} stress tensors"
            )));
        }
        let mut stress_points = Vec::with_capacity(m);
        for _ in 0..m {
            stress_points.push([r.f64()?, r.f64()?, r.f64()?]);
        }
        if r.at != bytes.len() {
            return Err(FemError::Invalid(format!(
                "joint solution bytes: {} trailing bytes after byte {}",
                bytes.len() - r.at,
                r.at
            )));
        }
        Ok(JointSolution {
            compliance,
            block_compliance,
            block_sections,
            asymmetry,
            k_bend,
            k_axial,
            k_torsion,
            layout,
            dofs,
            elements,
            residual,
            stress_basis,
            stress_points,
        })
    }
}

/// Little-endian reader over the bytes of an encoded solution.
pub(super) struct Reader<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], FemError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(FemError::Invalid(format!(
                "joint solution bytes: truncated ({} bytes, {n} more needed at byte {})",
                self.bytes.len(),
                self.at
            )));
        };
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }

    fn u64(&mut self) -> Result<u64, FemError> {
        let mut b = [0u8; 8];
        b.copy_from_slice(self.take(8)?);
        Ok(u64::from_le_bytes(b))
    }

    fn f64(&mut self) -> Result<f64, FemError> {
        self.u64().map(f64::from_bits)
    }

    fn f64s(&mut self, n: usize) -> Result<Vec<f64>, FemError> {
        (0..n).map(|_| self.f64()).collect()
    }

    /// A count whose items take `item` bytes each: refused if they cannot fit in what
    /// is left (so that a corrupt count never allocates).
    fn count(&mut self, item: usize) -> Result<usize, FemError> {
        let v = self.u64()?;
        let left = (self.bytes.len() - self.at) as u64;
        match usize::try_from(v) {
            Ok(n) if (n as u64).saturating_mul(item as u64) <= left => Ok(n),
            _ => Err(FemError::Invalid(format!(
                "joint solution bytes: count {v} at byte {} does not fit the {left} bytes left",
                self.at - 8
            ))),
        }
    }
}
