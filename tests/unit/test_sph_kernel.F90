! Kernel normalisation (integral of W = 1) in 1, 2 and 3 dimensions, and dW/dr against a
! central finite difference of W, for every kernel.
module test_sph_kernel
    use funit
    use sph_kinds, only: wp
    use sph_kernel, only: KERNEL_CUBIC, KERNEL_QUINTIC, KERNEL_WENDLAND_C2, kernel_w, &
        kernel_dwdr, kernel_support_factor, kernel_t, kernel_create
    implicit none

    real(wp), parameter :: pi = acos(-1.0_wp)
    integer, parameter :: kernels(3) = [KERNEL_CUBIC, KERNEL_QUINTIC, KERNEL_WENDLAND_C2]

contains

    !> Radial integral of W over all space: 2 int W dr (1D), 2 pi int W r dr (2D),
    !> 4 pi int W r^2 dr (3D), by composite Simpson on the support.
    real(wp) function integral_of_w(id, dim, h) result(total)
        integer, intent(in) :: id, dim
        real(wp), intent(in) :: h
        integer, parameter :: n = 20000
        integer :: k
        real(wp) :: r, dr, f, weight
        dr = kernel_support_factor(id) * h / n
        total = 0.0_wp
        do k = 0, n
            r = k * dr
            select case (dim)
            case (1); f = 2.0_wp * kernel_w(id, dim, r, h)
            case (2); f = 2.0_wp * pi * r * kernel_w(id, dim, r, h)
            case default; f = 4.0_wp * pi * r * r * kernel_w(id, dim, r, h)
            end select
            weight = merge(1.0_wp, merge(4.0_wp, 2.0_wp, mod(k, 2) == 1), k == 0 .or. k == n)
            total = total + weight * f
        end do
        total = total * dr / 3.0_wp
    end function integral_of_w

    !@test
    subroutine test_normalisation_all_kernels_and_dimensions()
        integer :: k, dim
        real(wp) :: total
        do k = 1, size(kernels)
            do dim = 1, 3
                total = integral_of_w(kernels(k), dim, 0.37_wp)
#line 45 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertEqual(1.0_wp, total, 1.0e-9_wp, 'integral of W over space is 1', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 45) )
  if (anyExceptions()) return
#line 46 "/work/main/tests/unit/test_sph_kernel.pf"
            end do
        end do
    end subroutine test_normalisation_all_kernels_and_dimensions

    !@test
    subroutine test_gradient_matches_finite_difference()
        integer :: k, dim, i
        real(wp) :: h, r, step, fd, analytic, tol
        h = 1.3_wp
        step = 1.0e-6_wp
        do k = 1, size(kernels)
            do dim = 1, 3
                do i = 1, 29
                    r = 0.1_wp * i * h * kernel_support_factor(kernels(k)) / 3.0_wp
                    fd = (kernel_w(kernels(k), dim, r + step, h) - kernel_w(kernels(k), dim, r - step, h)) &
                        / (2.0_wp * step)
                    analytic = kernel_dwdr(kernels(k), dim, r, h)
                    tol = 1.0e-7_wp * max(1.0_wp, abs(fd))
#line 64 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertEqual(fd, analytic, tol, 'dW/dr equals the central difference of W', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 64) )
  if (anyExceptions()) return
#line 65 "/work/main/tests/unit/test_sph_kernel.pf"
                end do
            end do
        end do
    end subroutine test_gradient_matches_finite_difference

    !@test
    subroutine test_compact_support_and_positivity()
        integer :: k, id
        real(wp) :: h, edge, w, dw
        h = 0.5_wp
        do k = 1, size(kernels)
            id = kernels(k)
            edge = kernel_support_factor(id) * h
            w = kernel_w(id, 2, edge, h)
#line 79 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertEqual(0.0_wp, w, 'W vanishes at the support radius', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 79) )
  if (anyExceptions()) return
#line 80 "/work/main/tests/unit/test_sph_kernel.pf"
            dw = kernel_dwdr(id, 3, 1.01_wp * edge, h)
#line 81 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertEqual(0.0_wp, dw, 'dW/dr vanishes outside the support', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 81) )
  if (anyExceptions()) return
#line 82 "/work/main/tests/unit/test_sph_kernel.pf"
            w = kernel_w(id, 2, 0.5_wp * h, h)
#line 83 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertGreaterThan(w, 0.0_wp, message='W is positive inside the support', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 83) )
  if (anyExceptions()) return
#line 84 "/work/main/tests/unit/test_sph_kernel.pf"
            dw = kernel_dwdr(id, 2, 0.5_wp * h, h)
#line 85 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertLessThan(dw, 0.0_wp, message='W decreases with r', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 85) )
  if (anyExceptions()) return
#line 86 "/work/main/tests/unit/test_sph_kernel.pf"
            dw = kernel_dwdr(id, 2, 0.0_wp, h)
#line 87 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertEqual(0.0_wp, dw, 1.0e-12_wp, 'dW/dr is zero at the centre', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 87) )
  if (anyExceptions()) return
#line 88 "/work/main/tests/unit/test_sph_kernel.pf"
        end do
    end subroutine test_compact_support_and_positivity

    !@test
    subroutine test_kernel_object_matches_scalar_functions()
        type(kernel_t) :: kern
        integer :: k
        real(wp) :: r, expected, actual
        do k = 1, size(kernels)
            kern = kernel_create(kernels(k), 3, 0.8_wp)
            r = 0.77_wp
            expected = kernel_w(kernels(k), 3, r, 0.8_wp)
            actual = kern%w(r)
#line 101 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertRelativelyEqual(expected, actual, 1.0e-13_wp, 'kernel_t%w equals kernel_w', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 101) )
  if (anyExceptions()) return
#line 102 "/work/main/tests/unit/test_sph_kernel.pf"
            expected = kernel_dwdr(kernels(k), 3, r, 0.8_wp)
            actual = kern%dwdr(r)
#line 104 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertRelativelyEqual(expected, actual, 1.0e-13_wp, 'kernel_t%dwdr equals kernel_dwdr', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 104) )
  if (anyExceptions()) return
#line 105 "/work/main/tests/unit/test_sph_kernel.pf"
            expected = kernel_support_factor(kernels(k)) * 0.8_wp
#line 106 "/work/main/tests/unit/test_sph_kernel.pf"
  call assertEqual(expected, kern%support, 1.0e-15_wp, 'support radius is q_max h', &
 & location=SourceLocation( &
 & 'test_sph_kernel.pf', &
 & 106) )
  if (anyExceptions()) return
#line 107 "/work/main/tests/unit/test_sph_kernel.pf"
        end do
    end subroutine test_kernel_object_matches_scalar_functions
end module test_sph_kernel

module Wraptest_sph_kernel
   use FUnit
   use test_sph_kernel
   implicit none
   private

contains


end module Wraptest_sph_kernel

function test_sph_kernel_suite() result(suite)
   use FUnit
   use test_sph_kernel
   use Wraptest_sph_kernel
   implicit none
   type (TestSuite) :: suite

   class (Test), allocatable :: t

   suite = TestSuite('test_sph_kernel_suite')

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_normalisation_all_kernels_and_dimensions', &
      test_normalisation_all_kernels_and_dimensions))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_gradient_matches_finite_difference', &
      test_gradient_matches_finite_difference))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_compact_support_and_positivity', &
      test_compact_support_and_positivity))
   call suite%addTest(t)

   if(allocated(t)) deallocate(t)
   allocate(t, source=TestMethod('test_kernel_object_matches_scalar_functions', &
      test_kernel_object_matches_scalar_functions))
   call suite%addTest(t)


end function test_sph_kernel_suite

