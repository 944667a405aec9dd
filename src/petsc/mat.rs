//! Distributed sparse matrices (`MATAIJ`, block size 3) with exact preallocation.

use super::error::{check, Result};
use super::{sys, to_petsc_int, Petsc, PetscInt, Vector};
use std::marker::PhantomData;

/// Whether two matrices share their nonzero pattern (lets `axpy` skip a symbolic merge).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NonzeroPattern {
    Same,
    Subset,
    Different,
}

pub struct Mat<'p> {
    raw: sys::Mat,
    _runtime: PhantomData<&'p Petsc>,
}

impl<'p> Mat<'p> {
    /// A square AIJ matrix over the runtime's world communicator, preallocated row by row.
    ///
    /// `diag_nnz[i]`/`offdiag_nnz[i]` count the nonzeros of local row `i` in the columns this rank
    /// owns and in the others. With exact counts assembly performs no mallocs; any entry outside the
    /// preallocated pattern is turned into an error (`MAT_NEW_NONZERO_ALLOCATION_ERR`) instead of a
    /// silent slow path.
    pub fn new_aij(
        petsc: &'p Petsc,
        local_rows: usize,
        global_rows: usize,
        block_size: usize,
        diag_nnz: &[PetscInt],
        offdiag_nnz: &[PetscInt],
    ) -> Result<Self> {
        assert_eq!(diag_nnz.len(), local_rows);
        assert_eq!(offdiag_nnz.len(), local_rows);
        let mut raw: sys::Mat = std::ptr::null_mut();
        let (n, big_n, bs) = (
            to_petsc_int(local_rows)?,
            to_petsc_int(global_rows)?,
            to_petsc_int(block_size)?,
        );
        // SAFETY: standard creation sequence; arrays outlive the calls, PETSc copies them.
        unsafe {
            check(sys::MatCreate(petsc.comm(), &mut raw), "MatCreate")?;
            let mat = Mat {
                raw,
                _runtime: PhantomData,
            };
            check(sys::MatSetSizes(raw, n, n, big_n, big_n), "MatSetSizes")?;
            check(
                sys::MatSetType(raw, sys::MATAIJ.as_ptr() as _),
                "MatSetType",
            )?;
            check(sys::MatSetBlockSize(raw, bs), "MatSetBlockSize")?;
            check(
                sys::MatSeqAIJSetPreallocation(raw, 0, diag_nnz.as_ptr()),
                "MatSeqAIJSetPreallocation",
            )?;
            check(
                sys::MatMPIAIJSetPreallocation(raw, 0, diag_nnz.as_ptr(), 0, offdiag_nnz.as_ptr()),
                "MatMPIAIJSetPreallocation",
            )?;
            check(
                sys::MatSetOption(
                    raw,
                    sys::MatOption_MAT_NEW_NONZERO_ALLOCATION_ERR,
                    sys::PetscBool_PETSC_TRUE,
                ),
                "MatSetOption",
            )?;
            Ok(mat)
        }
    }

    /// A square AIJ matrix from this rank's rows in CSR form (global column indices, sorted
    /// within each row). PETSc takes the exact pattern and the values in one call, so there is no
    /// preallocation guesswork and no stash traffic: every rank must supply complete rows.
    pub fn from_csr(
        petsc: &'p Petsc,
        global_rows: usize,
        block_size: usize,
        row_ptr: &[PetscInt],
        cols: &[PetscInt],
        values: &[f64],
    ) -> Result<Self> {
        let local_rows = row_ptr.len() - 1;
        Self::from_csr_rectangular(
            petsc,
            (local_rows, global_rows),
            (local_rows, global_rows),
            block_size,
            row_ptr,
            cols,
            values,
        )
    }

    /// [`Mat::from_csr`] for a rectangular matrix: `rows` and `columns` are (this rank's part,
    /// global size); the local columns are this rank's part of a vector the matrix multiplies
    /// (an interpolation from a coarse space, say). Both dimensions share `block_size`.
    pub fn from_csr_rectangular(
        petsc: &'p Petsc,
        rows: (usize, usize),
        columns: (usize, usize),
        block_size: usize,
        row_ptr: &[PetscInt],
        cols: &[PetscInt],
        values: &[f64],
    ) -> Result<Self> {
        let local_rows = row_ptr.len() - 1;
        assert_eq!(local_rows, rows.0);
        assert_eq!(cols.len(), values.len());
        assert_eq!(row_ptr[local_rows] as usize, cols.len());
        let mut raw: sys::Mat = std::ptr::null_mut();
        let (m, big_m, n, big_n, bs) = (
            to_petsc_int(rows.0)?,
            to_petsc_int(rows.1)?,
            to_petsc_int(columns.0)?,
            to_petsc_int(columns.1)?,
            to_petsc_int(block_size)?,
        );
        // SAFETY: PETSc copies the three arrays; they outlive the calls.
        unsafe {
            check(sys::MatCreate(petsc.comm(), &mut raw), "MatCreate")?;
            let mut mat = Mat {
                raw,
                _runtime: PhantomData,
            };
            check(sys::MatSetSizes(raw, m, n, big_m, big_n), "MatSetSizes")?;
            check(
                sys::MatSetType(raw, sys::MATAIJ.as_ptr() as _),
                "MatSetType",
            )?;
            check(sys::MatSetBlockSize(raw, bs), "MatSetBlockSize")?;
            if petsc.size() == 1 {
                check(
                    sys::MatSeqAIJSetPreallocationCSR(
                        raw,
                        row_ptr.as_ptr(),
                        cols.as_ptr(),
                        values.as_ptr(),
                    ),
                    "MatSeqAIJSetPreallocationCSR",
                )?;
            } else {
                check(
                    sys::MatMPIAIJSetPreallocationCSR(
                        raw,
                        row_ptr.as_ptr(),
                        cols.as_ptr(),
                        values.as_ptr(),
                    ),
                    "MatMPIAIJSetPreallocationCSR",
                )?;
            }
            check(
                sys::MatSetOption(
                    raw,
                    sys::MatOption_MAT_NEW_NONZERO_ALLOCATION_ERR,
                    sys::PetscBool_PETSC_TRUE,
                ),
                "MatSetOption",
            )?;
            mat.assemble()?;
            Ok(mat)
        }
    }

    /// The Galerkin product Πᵀ·self·Π (PETSc's MatPtAP), a new matrix on Π's column layout;
    /// `fill` is PETSc's estimate of nnz(result)/(nnz(self) + nnz(Π)) (2 is its default).
    pub fn ptap(&self, interpolation: &Mat<'p>, fill: f64) -> Result<Mat<'p>> {
        let mut raw: sys::Mat = std::ptr::null_mut();
        // SAFETY: both matrices are assembled and on one communicator; PETSc creates the result.
        unsafe {
            check(
                sys::MatPtAP(
                    self.raw,
                    interpolation.raw,
                    sys::MatReuse_MAT_INITIAL_MATRIX,
                    fill,
                    &mut raw,
                ),
                "MatPtAP",
            )?
        };
        Ok(Mat {
            raw,
            _runtime: PhantomData,
        })
    }

    /// `y ← selfᵀ·x`.
    pub fn mult_transpose(&self, x: &Vector<'p>, y: &mut Vector<'p>) -> Result<()> {
        // SAFETY: vectors come from `create_vectors`, so their layouts match.
        unsafe {
            check(
                sys::MatMultTranspose(self.raw, x.raw(), y.raw()),
                "MatMultTranspose",
            )
        }
    }

    /// A vector of the matrix's column layout (the input of `mult`) and one of its row layout.
    pub fn create_vectors(&self) -> Result<(Vector<'p>, Vector<'p>)> {
        let (mut right, mut left): (sys::Vec, sys::Vec) =
            (std::ptr::null_mut(), std::ptr::null_mut());
        // SAFETY: PETSc allocates compatible vectors.
        unsafe {
            check(
                sys::MatCreateVecs(self.raw, &mut right, &mut left),
                "MatCreateVecs",
            )?
        };
        Ok((Vector::from_raw(right), Vector::from_raw(left)))
    }

    pub fn raw(&self) -> sys::Mat {
        self.raw
    }

    /// Adds a dense `rows × cols` block (row-major) into the matrix; off-rank rows are stashed
    /// and sent during [`Mat::assemble`].
    pub fn add_values(
        &mut self,
        rows: &[PetscInt],
        cols: &[PetscInt],
        values: &[f64],
    ) -> Result<()> {
        debug_assert_eq!(values.len(), rows.len() * cols.len());
        // SAFETY: lengths are passed with the pointers.
        unsafe {
            check(
                sys::MatSetValues(
                    self.raw,
                    rows.len() as PetscInt,
                    rows.as_ptr(),
                    cols.len() as PetscInt,
                    cols.as_ptr(),
                    values.as_ptr(),
                    sys::InsertMode_ADD_VALUES,
                ),
                "MatSetValues",
            )
        }
    }

    /// Final assembly: communicates stashed off-rank entries.
    pub fn assemble(&mut self) -> Result<()> {
        // SAFETY: collective on the matrix communicator; all ranks call it in the same order.
        unsafe {
            check(
                sys::MatAssemblyBegin(self.raw, sys::MatAssemblyType_MAT_FINAL_ASSEMBLY),
                "MatAssemblyBegin",
            )?;
            check(
                sys::MatAssemblyEnd(self.raw, sys::MatAssemblyType_MAT_FINAL_ASSEMBLY),
                "MatAssemblyEnd",
            )
        }
    }

    /// Marks the matrix symmetric for good, which MUMPS Cholesky on AIJ relies on.
    pub fn set_symmetric(&mut self) -> Result<()> {
        // SAFETY: option setting only.
        unsafe {
            check(
                sys::MatSetOption(
                    self.raw,
                    sys::MatOption_MAT_SYMMETRIC,
                    sys::PetscBool_PETSC_TRUE,
                ),
                "MatSetOption(SYMMETRIC)",
            )?;
            check(
                sys::MatSetOption(
                    self.raw,
                    sys::MatOption_MAT_SYMMETRY_ETERNAL,
                    sys::PetscBool_PETSC_TRUE,
                ),
                "MatSetOption(SYMMETRY_ETERNAL)",
            )
        }
    }

    /// A copy with the same values.
    pub fn duplicate(&self) -> Result<Mat<'p>> {
        let mut raw: sys::Mat = std::ptr::null_mut();
        // SAFETY: creates a new independent matrix.
        unsafe {
            check(
                sys::MatDuplicate(self.raw, sys::MatDuplicateOption_MAT_COPY_VALUES, &mut raw),
                "MatDuplicate",
            )?
        };
        Ok(Mat {
            raw,
            _runtime: PhantomData,
        })
    }

    /// The whole matrix on this rank alone: a sequential AIJ copy (`PETSC_COMM_SELF`, rows and
    /// columns in the global numbering), made on every rank at once. For work that each rank
    /// then does on its own, with no communication. Collective.
    pub fn sequential_copy(&self) -> Result<Mat<'p>> {
        let (mut m, mut n) = (0, 0);
        // SAFETY: the index set, the array of submatrices and our extra reference are released on
        // every path; the copy keeps one reference, owned by the returned value.
        unsafe {
            check(sys::MatGetSize(self.raw, &mut m, &mut n), "MatGetSize")?;
            let mut rows: sys::IS = std::ptr::null_mut();
            let mut cols: sys::IS = std::ptr::null_mut();
            check(
                sys::ISCreateStride(mpi::ffi::RSMPI_COMM_SELF, m, 0, 1, &mut rows),
                "ISCreateStride",
            )?;
            if let Err(e) = check(
                sys::ISCreateStride(mpi::ffi::RSMPI_COMM_SELF, n, 0, 1, &mut cols),
                "ISCreateStride",
            ) {
                sys::ISDestroy(&mut rows);
                return Err(e);
            }
            let mut subs: *mut sys::Mat = std::ptr::null_mut();
            let made = check(
                sys::MatCreateSubMatrices(
                    self.raw,
                    1,
                    &rows,
                    &cols,
                    sys::MatReuse_MAT_INITIAL_MATRIX,
                    &mut subs,
                ),
                "MatCreateSubMatrices",
            );
            sys::ISDestroy(&mut rows);
            sys::ISDestroy(&mut cols);
            made?;
            let raw = *subs;
            // Our own reference first, so that destroying PETSc's array leaves the copy alive.
            let kept = check(
                sys::PetscObjectReference(raw as sys::PetscObject),
                "PetscObjectReference",
            );
            sys::MatDestroySubMatrices(1, &mut subs);
            kept?;
            Ok(Mat {
                raw,
                _runtime: PhantomData,
            })
        }
    }

    /// `self ← self + a·x`.
    pub fn axpy(&mut self, a: f64, x: &Mat<'p>, pattern: NonzeroPattern) -> Result<()> {
        let structure = match pattern {
            NonzeroPattern::Same => sys::MatStructure_SAME_NONZERO_PATTERN,
            NonzeroPattern::Subset => sys::MatStructure_SUBSET_NONZERO_PATTERN,
            NonzeroPattern::Different => sys::MatStructure_DIFFERENT_NONZERO_PATTERN,
        };
        // SAFETY: both matrices are assembled and on the same communicator.
        unsafe { check(sys::MatAXPY(self.raw, a, x.raw, structure), "MatAXPY") }
    }

    /// Attaches `basis` as the near-null space of this matrix, the space an algebraic multigrid
    /// preconditioner (PETSc's GAMG) must reproduce on its coarse levels: for elasticity the six
    /// rigid motions. MatNullSpaceCreate wants an orthonormal set (Euclidean inner product), so
    /// the vectors are orthonormalised here (modified Gram–Schmidt, twice); the matrix keeps its
    /// own reference.
    pub fn set_near_null_space(&mut self, petsc: &'p Petsc, basis: &[Vector<'p>]) -> Result<()> {
        let mut ortho: Vec<Vector<'p>> = Vec::with_capacity(basis.len());
        for v in basis {
            let mut w = v.duplicate()?;
            w.copy_from(v)?;
            for _ in 0..2 {
                for q in &ortho {
                    let c = q.dot(&w)?;
                    w.axpy(-c, q)?;
                }
            }
            let norm = w.norm2()?;
            if !(norm > 0.0) {
                return Err(super::PetscError::other(
                    "set_near_null_space: the basis vectors are linearly dependent",
                ));
            }
            w.scale(1.0 / norm)?;
            ortho.push(w);
        }
        let mut raw: Vec<sys::Vec> = ortho.iter().map(|v| v.raw()).collect();
        let mut space: sys::MatNullSpace = std::ptr::null_mut();
        // SAFETY: the vectors are live and of this matrix's layout; the null space and the matrix
        // take their own references, so ours are released when `ortho` drops.
        unsafe {
            check(
                sys::MatNullSpaceCreate(
                    petsc.comm(),
                    sys::PetscBool_PETSC_FALSE,
                    to_petsc_int(raw.len())?,
                    raw.as_mut_ptr(),
                    &mut space,
                ),
                "MatNullSpaceCreate",
            )?;
            let set = check(
                sys::MatSetNearNullSpace(self.raw, space),
                "MatSetNearNullSpace",
            );
            sys::MatNullSpaceDestroy(&mut space);
            set
        }
    }

    /// `self ← a·self`.
    pub fn scale(&mut self, a: f64) -> Result<()> {
        // SAFETY: in-place scaling.
        unsafe { check(sys::MatScale(self.raw, a), "MatScale") }
    }

    /// `y ← self·x`.
    pub fn mult(&self, x: &Vector<'p>, y: &mut Vector<'p>) -> Result<()> {
        // SAFETY: vectors come from `create_vector`, so their layouts match.
        unsafe { check(sys::MatMult(self.raw, x.raw(), y.raw()), "MatMult") }
    }

    /// A vector with the matrix's row layout.
    pub fn create_vector(&self) -> Result<Vector<'p>> {
        let mut raw: sys::Vec = std::ptr::null_mut();
        // SAFETY: PETSc allocates a compatible vector.
        unsafe {
            check(
                sys::MatCreateVecs(self.raw, &mut raw, std::ptr::null_mut()),
                "MatCreateVecs",
            )?
        };
        Ok(Vector::from_raw(raw))
    }

    /// The number of global rows (the system's size).
    pub fn global_rows(&self) -> Result<usize> {
        let (mut m, mut n) = (0, 0);
        // SAFETY: query only.
        unsafe { check(sys::MatGetSize(self.raw, &mut m, &mut n), "MatGetSize")? };
        Ok(m as usize)
    }

    /// The global rows `[start, end)` this rank owns.
    pub fn ownership_range(&self) -> Result<(usize, usize)> {
        let (mut lo, mut hi) = (0, 0);
        // SAFETY: query only.
        unsafe {
            check(
                sys::MatGetOwnershipRange(self.raw, &mut lo, &mut hi),
                "MatGetOwnershipRange",
            )?
        };
        Ok((lo as usize, hi as usize))
    }

    /// (nonzeros used, mallocs during assembly), summed over all ranks.
    pub fn global_info(&self) -> Result<(f64, f64)> {
        // SAFETY: MatInfo is plain data; PETSc fills it.
        unsafe {
            let mut info: sys::MatInfo = std::mem::zeroed();
            check(
                sys::MatGetInfo(self.raw, sys::MatInfoType_MAT_GLOBAL_SUM, &mut info),
                "MatGetInfo",
            )?;
            Ok((info.nz_used, info.mallocs))
        }
    }
}

impl Drop for Mat<'_> {
    fn drop(&mut self) {
        // SAFETY: we own the handle; the runtime is alive ('p).
        unsafe {
            sys::MatDestroy(&mut self.raw);
        }
    }
}
