//! Distributed dense matrices (`MATDENSE`): blocks of many vectors with one row layout, for
//! multi-right-hand-side solves (`MatMatSolve` on a MUMPS factor) and sparse × dense products.
//!
//! The local block is column-major, `local_rows × cols`, rows in the layout of the sparse
//! operators' vectors. Many columns at once cost far less than one vector at a time: MUMPS
//! reads its factor once per block of right-hand sides, and the product streams the sparse
//! matrix once for all columns.

use super::error::{check, Result};
use super::{sys, to_petsc_int, Mat, Petsc};
use std::marker::PhantomData;

pub struct Dense<'p> {
    raw: sys::Mat,
    local_rows: usize,
    cols: usize,
    _runtime: PhantomData<&'p Petsc>,
}

impl<'p> Dense<'p> {
    /// A zero dense matrix with `local_rows` rows on this rank (`global_rows` in all) and `cols`
    /// columns. Collective.
    pub fn zeros(
        petsc: &'p Petsc,
        local_rows: usize,
        global_rows: usize,
        cols: usize,
    ) -> Result<Self> {
        Self::zeros_on(petsc.comm(), local_rows, global_rows, cols)
    }

    /// A zero dense matrix of `rows × cols` on this rank alone (`PETSC_COMM_SELF`), for the
    /// sequential copies of [`Mat::sequential_copy`]. Not collective.
    pub fn zeros_sequential(_petsc: &'p Petsc, rows: usize, cols: usize) -> Result<Self> {
        // SAFETY: reads the address of MPI's predefined self communicator.
        let comm = unsafe { mpi::ffi::RSMPI_COMM_SELF };
        Self::zeros_on(comm, rows, rows, cols)
    }

    fn zeros_on(
        comm: mpi::ffi::MPI_Comm,
        local_rows: usize,
        global_rows: usize,
        cols: usize,
    ) -> Result<Self> {
        let mut raw: sys::Mat = std::ptr::null_mut();
        // SAFETY: PETSc allocates the storage (null data pointer); the handle is owned here.
        unsafe {
            check(
                sys::MatCreateDense(
                    comm,
                    to_petsc_int(local_rows)?,
                    sys::PETSC_DECIDE as _,
                    to_petsc_int(global_rows)?,
                    to_petsc_int(cols)?,
                    std::ptr::null_mut(),
                    &mut raw,
                ),
                "MatCreateDense",
            )?;
        }
        let mut m = Dense {
            raw,
            local_rows,
            cols,
            _runtime: PhantomData,
        };
        m.with_local(|x| x.fill(0.0))?;
        // SAFETY: assembles the (already filled) storage.
        unsafe {
            check(
                sys::MatAssemblyBegin(m.raw, sys::MatAssemblyType_MAT_FINAL_ASSEMBLY),
                "MatAssemblyBegin",
            )?;
            check(
                sys::MatAssemblyEnd(m.raw, sys::MatAssemblyType_MAT_FINAL_ASSEMBLY),
                "MatAssemblyEnd",
            )?;
        }
        Ok(m)
    }

    pub fn cols(&self) -> usize {
        self.cols
    }

    pub fn local_rows(&self) -> usize {
        self.local_rows
    }

    pub(crate) fn raw(&self) -> sys::Mat {
        self.raw
    }

    /// Runs `f` on this rank's block (column-major, `local_rows × cols`), read and write.
    pub fn with_local<T>(&mut self, f: impl FnOnce(&mut [f64]) -> T) -> Result<T> {
        let mut ptr: *mut f64 = std::ptr::null_mut();
        let mut lda: sys::PetscInt = 0;
        // SAFETY: PETSc hands out its own storage until the matching restore; the leading
        // dimension is checked so that the slice is exactly the block.
        unsafe {
            check(sys::MatDenseGetLDA(self.raw, &mut lda), "MatDenseGetLDA")?;
            if lda as usize != self.local_rows.max(1) && self.local_rows > 0 {
                return Err(super::PetscError::other(format!(
                    "dense block with leading dimension {lda} for {} local rows",
                    self.local_rows
                )));
            }
            check(
                sys::MatDenseGetArray(self.raw, &mut ptr as *mut *mut f64 as _),
                "MatDenseGetArray",
            )?;
            let n = self.local_rows * self.cols;
            let out = if n == 0 {
                f(&mut [])
            } else {
                f(std::slice::from_raw_parts_mut(ptr, n))
            };
            check(
                sys::MatDenseRestoreArray(self.raw, &mut ptr as *mut *mut f64 as _),
                "MatDenseRestoreArray",
            )?;
            Ok(out)
        }
    }

    /// A copy of this rank's block (column-major).
    pub fn local_values(&mut self) -> Result<Vec<f64>> {
        self.with_local(|x| x.to_vec())
    }

    /// `a · self` as a new dense matrix (rows in `a`'s layout). Collective.
    pub fn product(a: &Mat<'p>, x: &Dense<'p>) -> Result<Dense<'p>> {
        let mut raw: sys::Mat = std::ptr::null_mut();
        // SAFETY: PETSc creates the product; the handle is owned by the returned value.
        unsafe {
            check(
                sys::MatMatMult(
                    a.raw(),
                    x.raw,
                    sys::MatReuse_MAT_INITIAL_MATRIX,
                    sys::PETSC_DEFAULT as _,
                    &mut raw,
                ),
                "MatMatMult(AIJ, dense)",
            )?;
        }
        Ok(Dense {
            raw,
            local_rows: x.local_rows,
            cols: x.cols,
            _runtime: PhantomData,
        })
    }
}

impl Drop for Dense<'_> {
    fn drop(&mut self) {
        // SAFETY: we own the handle; the runtime is alive ('p).
        unsafe {
            sys::MatDestroy(&mut self.raw);
        }
    }
}
