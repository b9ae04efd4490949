!> Smoothing kernels W(r, h) and dW/dr, normalised in 1, 2 and 3 dimensions.
!>   cubic B-spline (thesis eq. 2.5; support 2h), quintic spline (Morris 1997; support 3h),
!>   Wendland C2 (support 2h; the 1-D member is the psi_{3,1} function).
!> The scalar functions are pure elemental with no module state; kernel_t caches the
!> per-run constants (sigma/h^d) for the particle loops. Chosen at run time by name.
!> kernel_t%dwdr_many evaluates a batch of distances (one particle's neighbours) with the
!> kernel chosen once, so the pair loops pay no call or kernel choice per pair.
module sph_kernel
    use sph_kinds, only: wp
    implicit none
    private
    public :: KERNEL_CUBIC, KERNEL_QUINTIC, KERNEL_WENDLAND_C2
    public :: kernel_t, kernel_create, kernel_id_from_name, kernel_name
    public :: kernel_w, kernel_dwdr, kernel_support_factor, kernel_default_h_factor
    public :: kernel_lattice_sum

    integer, parameter :: KERNEL_CUBIC = 1, KERNEL_QUINTIC = 2, KERNEL_WENDLAND_C2 = 3
    real(wp), parameter :: pi = acos(-1.0_wp)

    !> A kernel with its smoothing length fixed: what the particle loops use.
    type :: kernel_t
        integer :: id = KERNEL_CUBIC
        integer :: dim = 2
        real(wp) :: h = 1.0_wp
        real(wp) :: support = 2.0_wp       !< support radius, q_max * h
        real(wp) :: inv_h = 1.0_wp
        real(wp) :: w_norm = 1.0_wp        !< sigma_d / h^d
        real(wp) :: dw_norm = 1.0_wp       !< sigma_d / h^(d+1)
    contains
        procedure :: w => kernel_t_w
        procedure :: dwdr => kernel_t_dwdr
        procedure :: dwdr_many => kernel_t_dwdr_many
        procedure :: w_many => kernel_t_w_many
    end type kernel_t

contains

    !> A kernel of the given id in dim dimensions with smoothing length h (normalisation cached).
    function kernel_create(id, dim, h) result(k)
        integer, intent(in) :: id, dim
        real(wp), intent(in) :: h
        type(kernel_t) :: k
        k%id = id
        k%dim = dim
        k%h = h
        k%inv_h = 1.0_wp / h
        k%support = kernel_support_factor(id) * h
        k%w_norm = sigma(id, dim) / h**dim
        k%dw_norm = k%w_norm / h
    end function kernel_create

    !> Kernel id for a namelist name; 0 when unknown.
    integer function kernel_id_from_name(name)
        character(len=*), intent(in) :: name
        select case (trim(name))
        case ('cubic'); kernel_id_from_name = KERNEL_CUBIC
        case ('quintic'); kernel_id_from_name = KERNEL_QUINTIC
        case ('wendland_c2'); kernel_id_from_name = KERNEL_WENDLAND_C2
        case default; kernel_id_from_name = 0
        end select
    end function kernel_id_from_name

    !> The input name of a kernel id ('cubic', 'quintic', 'wendland_c2').
    function kernel_name(id) result(name)
        integer, intent(in) :: id
        character(len=:), allocatable :: name
        select case (id)
        case (KERNEL_CUBIC); name = 'cubic'
        case (KERNEL_QUINTIC); name = 'quintic'
        case (KERNEL_WENDLAND_C2); name = 'wendland_c2'
        case default; name = 'unknown'
        end select
    end function kernel_name

    !> Support radius in units of h.
    pure elemental real(wp) function kernel_support_factor(id)
        integer, intent(in) :: id
        select case (id)
        case (KERNEL_QUINTIC); kernel_support_factor = 3.0_wp
        case default; kernel_support_factor = 2.0_wp
        end select
    end function kernel_support_factor

    !> h / dx giving about the usual neighbour count for each kernel.
    pure elemental real(wp) function kernel_default_h_factor(id)
        integer, intent(in) :: id
        select case (id)
        case (KERNEL_QUINTIC); kernel_default_h_factor = 1.0_wp
        case (KERNEL_WENDLAND_C2); kernel_default_h_factor = 1.5_wp
        case default; kernel_default_h_factor = 1.3_wp
        end select
    end function kernel_default_h_factor

    !> Normalisation sigma_d: W = sigma_d / h^d f(r/h).
    pure elemental real(wp) function sigma(id, dim)
        integer, intent(in) :: id, dim
        sigma = 0.0_wp
        select case (id)
        case (KERNEL_CUBIC)
            select case (dim)
            case (1); sigma = 2.0_wp / 3.0_wp
            case (2); sigma = 10.0_wp / (7.0_wp * pi)
            case (3); sigma = 1.0_wp / pi
            end select
        case (KERNEL_QUINTIC)
            select case (dim)
            case (1); sigma = 1.0_wp / 120.0_wp
            case (2); sigma = 7.0_wp / (478.0_wp * pi)
            case (3); sigma = 1.0_wp / (120.0_wp * pi)
            end select
        case (KERNEL_WENDLAND_C2)
            select case (dim)
            case (1); sigma = 5.0_wp / 8.0_wp
            case (2); sigma = 7.0_wp / (4.0_wp * pi)
            case (3); sigma = 21.0_wp / (16.0_wp * pi)
            end select
        end select
    end function sigma

    !> Shape f(q) without normalisation.
    pure elemental real(wp) function shape(id, dim, q)
        integer, intent(in) :: id, dim
        real(wp), intent(in) :: q
        shape = 0.0_wp
        select case (id)
        case (KERNEL_CUBIC)
            if (q < 1.0_wp) then
                shape = 1.0_wp - 1.5_wp * q**2 + 0.75_wp * q**3
            else if (q < 2.0_wp) then
                shape = 0.25_wp * (2.0_wp - q)**3
            end if
        case (KERNEL_QUINTIC)
            if (q < 3.0_wp) shape = (3.0_wp - q)**5
            if (q < 2.0_wp) shape = shape - 6.0_wp * (2.0_wp - q)**5
            if (q < 1.0_wp) shape = shape + 15.0_wp * (1.0_wp - q)**5
        case (KERNEL_WENDLAND_C2)
            if (q < 2.0_wp) then
                if (dim == 1) then
                    shape = (1.0_wp - 0.5_wp * q)**3 * (1.5_wp * q + 1.0_wp)
                else
                    shape = (1.0_wp - 0.5_wp * q)**4 * (2.0_wp * q + 1.0_wp)
                end if
            end if
        end select
    end function shape

    !> df/dq.
    pure elemental real(wp) function shape_derivative(id, dim, q)
        integer, intent(in) :: id, dim
        real(wp), intent(in) :: q
        shape_derivative = 0.0_wp
        select case (id)
        case (KERNEL_CUBIC)
            shape_derivative = cubic_derivative(q)
        case (KERNEL_QUINTIC)
            if (q < 3.0_wp) shape_derivative = -5.0_wp * (3.0_wp - q)**4
            if (q < 2.0_wp) shape_derivative = shape_derivative + 30.0_wp * (2.0_wp - q)**4
            if (q < 1.0_wp) shape_derivative = shape_derivative - 75.0_wp * (1.0_wp - q)**4
        case (KERNEL_WENDLAND_C2)
            if (q < 2.0_wp) then
                if (dim == 1) then
                    ! product rule on (1 - q/2)^3 (1.5 q + 1)
                    shape_derivative = -1.5_wp * (1.0_wp - 0.5_wp * q)**2 * (1.5_wp * q + 1.0_wp) &
                        + 1.5_wp * (1.0_wp - 0.5_wp * q)**3
                else
                    shape_derivative = -5.0_wp * q * (1.0_wp - 0.5_wp * q)**3
                end if
            end if
        end select
    end function shape_derivative

    !> df/dq of the cubic spline.
    pure elemental real(wp) function cubic_derivative(q)
        real(wp), intent(in) :: q
        cubic_derivative = 0.0_wp
        if (q < 1.0_wp) then
            cubic_derivative = -3.0_wp * q + 2.25_wp * q**2
        else if (q < 2.0_wp) then
            cubic_derivative = -0.75_wp * (2.0_wp - q)**2
        end if
    end function cubic_derivative

    !> W(r, h) for a kernel id in dim dimensions.
    pure elemental real(wp) function kernel_w(id, dim, r, h)
        integer, intent(in) :: id, dim
        real(wp), intent(in) :: r, h
        kernel_w = sigma(id, dim) / h**dim * shape(id, dim, r / h)
    end function kernel_w

    !> dW/dr (r, h); the gradient is (x_i - x_j)/r * dW/dr.
    pure elemental real(wp) function kernel_dwdr(id, dim, r, h)
        integer, intent(in) :: id, dim
        real(wp), intent(in) :: r, h
        kernel_dwdr = sigma(id, dim) / h**(dim + 1) * shape_derivative(id, dim, r / h)
    end function kernel_dwdr

    pure real(wp) function kernel_t_w(self, r)
        class(kernel_t), intent(in) :: self
        real(wp), intent(in) :: r
        kernel_t_w = self%w_norm * shape(self%id, self%dim, r * self%inv_h)
    end function kernel_t_w

    pure real(wp) function kernel_t_dwdr(self, r)
        class(kernel_t), intent(in) :: self
        real(wp), intent(in) :: r
        kernel_t_dwdr = self%dw_norm * shape_derivative(self%id, self%dim, r * self%inv_h)
    end function kernel_t_dwdr

    !> dwdr(k) = dW/dr (r(k)) for k = 1..size(r), the values of self%dwdr(r(k)) to round-off
    !> (the pieces without branches, so the loops vectorise).
    pure subroutine kernel_t_dwdr_many(self, r, dwdr)
        class(kernel_t), intent(in) :: self
        real(wp), intent(in) :: r(:)
        real(wp), intent(out) :: dwdr(:)
        integer :: k
        real(wp) :: q
        select case (self%id)
        case (KERNEL_CUBIC)
            ! cubic_derivative without branches (both pieces, one chosen), so the loop
            ! vectorises; beyond q = 2 the second piece is -0
            do k = 1, size(r)
                q = r(k) * self%inv_h
                dwdr(k) = self%dw_norm * merge(-3.0_wp * q + 2.25_wp * q**2, &
                    -0.75_wp * max(2.0_wp - q, 0.0_wp)**2, q < 1.0_wp)
            end do
        case (KERNEL_QUINTIC)
            ! shape_derivative's three terms, each clamped instead of tested
            do k = 1, size(r)
                q = r(k) * self%inv_h
                dwdr(k) = self%dw_norm * (-5.0_wp * max(3.0_wp - q, 0.0_wp)**4 + 30.0_wp * &
                    max(2.0_wp - q, 0.0_wp)**4 - 75.0_wp * max(1.0_wp - q, 0.0_wp)**4)
            end do
        case (KERNEL_WENDLAND_C2)
            if (self%dim == 1) then
                do k = 1, size(r)
                    dwdr(k) = self%dw_norm * shape_derivative(self%id, self%dim, &
                        r(k) * self%inv_h)
                end do
            else
                do k = 1, size(r)
                    q = r(k) * self%inv_h
                    dwdr(k) = self%dw_norm * (-5.0_wp * q * max(1.0_wp - 0.5_wp * q, 0.0_wp)**3)
                end do
            end if
        case default
            do k = 1, size(r)
                dwdr(k) = self%dw_norm * shape_derivative(self%id, self%dim, r(k) * self%inv_h)
            end do
        end select
    end subroutine kernel_t_dwdr_many

    !> W of a batch of distances (as dwdr_many: the kernel chosen once, the cubic's pieces
    !> without branches).
    pure subroutine kernel_t_w_many(self, r, w)
        class(kernel_t), intent(in) :: self
        real(wp), intent(in) :: r(:)
        real(wp), intent(out) :: w(:)
        integer :: k
        real(wp) :: q
        select case (self%id)
        case (KERNEL_CUBIC)
            do k = 1, size(r)
                q = r(k) * self%inv_h
                w(k) = self%w_norm * merge(1.0_wp - 1.5_wp * q**2 + 0.75_wp * q**3, &
                    0.25_wp * max(2.0_wp - q, 0.0_wp)**3, q < 1.0_wp)
            end do
        case default
            do k = 1, size(r)
                w(k) = self%w_norm * shape(self%id, self%dim, r(k) * self%inv_h)
            end do
        end select
    end subroutine kernel_t_w_many

    !> sum_n W(|n| dx) over the points n dx of the integer lattice in dim dimensions: a
    !> lattice's kernel sum of unit masses (times dx^dim: 1.0051 for the Wendland C2 kernel
    !> at h = 1.5 dx in 2D, 1.0031 in 3D; 0.99995 for the cubic spline at 1.3 dx in 2D,
    !> 0.9973 in 3D).
    real(wp) function kernel_lattice_sum(kernel, dx, dim) result(total)
        type(kernel_t), intent(in) :: kernel
        real(wp), intent(in) :: dx
        integer, intent(in) :: dim
        integer :: a, b, c, reach, c_reach
        real(wp) :: r
        reach = ceiling(kernel%support / dx)
        c_reach = merge(reach, 0, dim == 3)
        total = 0.0_wp
        do c = -c_reach, c_reach
            do b = -reach, reach
                do a = -reach, reach
                    r = dx * sqrt(real(a * a + b * b + c * c, wp))
                    if (r < kernel%support) total = total + kernel%w(r)
                end do
            end do
        end do
    end function kernel_lattice_sum
end module sph_kernel
