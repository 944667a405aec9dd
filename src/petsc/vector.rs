//! Distributed vectors.

use super::error::{check, Result};
use super::{sys, Petsc};
use std::marker::PhantomData;

pub struct Vector<'p> {
    raw: sys::Vec,
    _runtime: PhantomData<&'p Petsc>,
}

impl<'p> Vector<'p> {
    pub(crate) fn from_raw(raw: sys::Vec) -> Self {
        Vector {
            raw,
            _runtime: PhantomData,
        }
    }

    pub fn raw(&self) -> sys::Vec {
        self.raw
    }

    pub fn duplicate(&self) -> Result<Vector<'p>> {
        let mut raw: sys::Vec = std::ptr::null_mut();
        // SAFETY: new vector with the same layout.
        unsafe { check(sys::VecDuplicate(self.raw, &mut raw), "VecDuplicate")? };
        Ok(Vector::from_raw(raw))
    }

    /// `self ← x` (same layout).
    pub fn copy_from(&mut self, x: &Vector<'p>) -> Result<()> {
        // SAFETY: both vectors are live and share a layout (PETSc checks the sizes).
        unsafe { check(sys::VecCopy(x.raw, self.raw), "VecCopy") }
    }

    pub fn global_size(&self) -> Result<usize> {
        let mut n = 0;
        // SAFETY: query only.
        unsafe { check(sys::VecGetSize(self.raw, &mut n), "VecGetSize")? };
        Ok(n as usize)
    }

    pub fn ownership_range(&self) -> Result<(usize, usize)> {
        let (mut lo, mut hi) = (0, 0);
        // SAFETY: query only.
        unsafe {
            check(
                sys::VecGetOwnershipRange(self.raw, &mut lo, &mut hi),
                "VecGetOwnershipRange",
            )?
        };
        Ok((lo as usize, hi as usize))
    }

    /// A copy of the locally owned entries.
    pub fn local_values(&self) -> Result<Vec<f64>> {
        let (lo, hi) = self.ownership_range()?;
        let mut ptr: *const f64 = std::ptr::null();
        // SAFETY: PETSc hands out a read pointer to `hi - lo` entries until the restore.
        unsafe {
            check(sys::VecGetArrayRead(self.raw, &mut ptr), "VecGetArrayRead")?;
            let out = std::slice::from_raw_parts(ptr, hi - lo).to_vec();
            check(
                sys::VecRestoreArrayRead(self.raw, &mut ptr),
                "VecRestoreArrayRead",
            )?;
            Ok(out)
        }
    }

    /// Overwrites the locally owned entries.
    pub fn set_local_values(&mut self, values: &[f64]) -> Result<()> {
        let (lo, hi) = self.ownership_range()?;
        if values.len() != hi - lo {
            return Err(super::PetscError::other(format!(
                "set_local_values: {} values for {} local entries",
                values.len(),
                hi - lo
            )));
        }
        let mut ptr: *mut f64 = std::ptr::null_mut();
        // SAFETY: as above, with a write pointer.
        unsafe {
            check(sys::VecGetArray(self.raw, &mut ptr), "VecGetArray")?;
            std::slice::from_raw_parts_mut(ptr, hi - lo).copy_from_slice(values);
            check(sys::VecRestoreArray(self.raw, &mut ptr), "VecRestoreArray")
        }
    }

    pub fn dot(&self, other: &Vector<'p>) -> Result<f64> {
        let mut d = 0.0;
        // SAFETY: collective reduction.
        unsafe { check(sys::VecDot(self.raw, other.raw, &mut d), "VecDot")? };
        Ok(d)
    }

    pub fn norm2(&self) -> Result<f64> {
        let mut n = 0.0;
        // SAFETY: collective reduction.
        unsafe {
            check(
                sys::VecNorm(self.raw, sys::NormType_NORM_2, &mut n),
                "VecNorm",
            )?
        };
        Ok(n)
    }

    pub fn scale(&mut self, a: f64) -> Result<()> {
        // SAFETY: in place.
        unsafe { check(sys::VecScale(self.raw, a), "VecScale") }
    }

    /// `self ← self + a·x`.
    pub fn axpy(&mut self, a: f64, x: &Vector<'p>) -> Result<()> {
        // SAFETY: same layout.
        unsafe { check(sys::VecAXPY(self.raw, a, x.raw), "VecAXPY") }
    }

    /// The entries at the given global indices, on this rank (each rank asks for its own list,
    /// typically its owned entries plus the ghosts its elements need). Collective.
    pub fn gather_indices(&self, indices: &[super::PetscInt]) -> Result<Vec<f64>> {
        let n = super::to_petsc_int(indices.len())?;
        let mut is_from: sys::IS = std::ptr::null_mut();
        let mut local: sys::Vec = std::ptr::null_mut();
        let mut scatter: sys::VecScatter = std::ptr::null_mut();
        // SAFETY: every object created here is destroyed before returning; PETSc copies the
        // index array (PETSC_COPY_VALUES).
        unsafe {
            let self_comm = mpi::ffi::RSMPI_COMM_SELF;
            check(
                sys::ISCreateGeneral(
                    self_comm,
                    n,
                    indices.as_ptr(),
                    sys::PetscCopyMode_PETSC_COPY_VALUES,
                    &mut is_from,
                ),
                "ISCreateGeneral",
            )?;
            let result = (|| {
                check(sys::VecCreateSeq(self_comm, n, &mut local), "VecCreateSeq")?;
                check(
                    sys::VecScatterCreate(
                        self.raw,
                        is_from,
                        local,
                        std::ptr::null_mut(),
                        &mut scatter,
                    ),
                    "VecScatterCreate",
                )?;
                check(
                    sys::VecScatterBegin(
                        scatter,
                        self.raw,
                        local,
                        sys::InsertMode_INSERT_VALUES,
                        sys::ScatterMode_SCATTER_FORWARD,
                    ),
                    "VecScatterBegin",
                )?;
                check(
                    sys::VecScatterEnd(
                        scatter,
                        self.raw,
                        local,
                        sys::InsertMode_INSERT_VALUES,
                        sys::ScatterMode_SCATTER_FORWARD,
                    ),
                    "VecScatterEnd",
                )?;
                let mut ptr: *const f64 = std::ptr::null();
                check(sys::VecGetArrayRead(local, &mut ptr), "VecGetArrayRead")?;
                let out = if indices.is_empty() {
                    Vec::new()
                } else {
                    std::slice::from_raw_parts(ptr, indices.len()).to_vec()
                };
                check(
                    sys::VecRestoreArrayRead(local, &mut ptr),
                    "VecRestoreArrayRead",
                )?;
                Ok(out)
            })();
            if !scatter.is_null() {
                sys::VecScatterDestroy(&mut scatter);
            }
            if !local.is_null() {
                sys::VecDestroy(&mut local);
            }
            sys::ISDestroy(&mut is_from);
            result
        }
    }

    /// The whole vector in global order on rank 0 (`None` elsewhere). Collective.
    pub fn gather_to_root(&self, rank: usize) -> Result<Option<Vec<f64>>> {
        let mut scatter: sys::VecScatter = std::ptr::null_mut();
        let mut full: sys::Vec = std::ptr::null_mut();
        // SAFETY: scatter context and target are destroyed before returning.
        unsafe {
            check(
                sys::VecScatterCreateToZero(self.raw, &mut scatter, &mut full),
                "VecScatterCreateToZero",
            )?;
            let full = Vector::<'p>::from_raw(full);
            let result = (|| {
                check(
                    sys::VecScatterBegin(
                        scatter,
                        self.raw,
                        full.raw,
                        sys::InsertMode_INSERT_VALUES,
                        sys::ScatterMode_SCATTER_FORWARD,
                    ),
                    "VecScatterBegin",
                )?;
                check(
                    sys::VecScatterEnd(
                        scatter,
                        self.raw,
                        full.raw,
                        sys::InsertMode_INSERT_VALUES,
                        sys::ScatterMode_SCATTER_FORWARD,
                    ),
                    "VecScatterEnd",
                )?;
                if rank == 0 {
                    let n = full.global_size()?;
                    let mut ptr: *const f64 = std::ptr::null();
                    check(sys::VecGetArrayRead(full.raw, &mut ptr), "VecGetArrayRead")?;
                    let out = std::slice::from_raw_parts(ptr, n).to_vec();
                    check(
                        sys::VecRestoreArrayRead(full.raw, &mut ptr),
                        "VecRestoreArrayRead",
                    )?;
                    Ok(Some(out))
                } else {
                    Ok(None)
                }
            })();
            sys::VecScatterDestroy(&mut scatter);
            result
        }
    }
}

impl Drop for Vector<'_> {
    fn drop(&mut self) {
        // SAFETY: we own the handle.
        unsafe {
            sys::VecDestroy(&mut self.raw);
        }
    }
}
