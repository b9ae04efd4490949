!> Particle storage: structure of arrays. Each rank holds its owned particles in 1:n_owned,
!> followed by ghost copies (periodic images and other ranks' particles within reach, made by
!> the halo exchange) in n_owned+1:n_owned+n_ghost, followed by per-stage virtual copies (wall
!> mirror images) up to n_total. Physics loops update owned particles only and read all.
module sph_particles
    use sph_kinds, only: wp, i8
    implicit none
    private
    public :: particles_t, particles_init, particles_free, particles_reserve
    public :: particles_copy, particles_pack, particles_unpack, particles_permute_owned
    public :: KIND_FLUID, KIND_WALL, KIND_VIRTUAL, KIND_MIRROR, pack_size

    integer, parameter :: KIND_FLUID = 0    !< moves with the flow
    integer, parameter :: KIND_WALL = 1     !< fixed wall particle, carries its wall's velocity
    integer, parameter :: KIND_VIRTUAL = 2  !< remeshing: particle of the other resolution level
    integer, parameter :: KIND_MIRROR = 3   !< type-2 mirror image, rebuilt each stage, never output

    !> Values per particle in a pack buffer (see particles_pack for the layout).
    integer, parameter :: pack_size = 40

    type :: particles_t
        integer :: n_owned = 0
        integer :: n_ghost = 0
        integer :: n_total = 0        !< owned + ghost + mirror
        integer :: capacity = 0
        integer :: dim = 2
        ! state
        real(wp), allocatable :: x(:, :)        !< position (3, n); z unused in 2D
        real(wp), allocatable :: v(:, :)        !< velocity (3, n)
        real(wp), allocatable :: rho(:)         !< density
        real(wp), allocatable :: p(:)           !< pressure
        real(wp), allocatable :: m(:)           !< mass
        real(wp), allocatable :: h(:)           !< smoothing length
        real(wp), allocatable :: e(:)           !< specific internal energy
        ! time derivatives
        real(wp), allocatable :: dvdt(:, :)
        real(wp), allocatable :: drhodt(:)
        real(wp), allocatable :: dedt(:)
        ! predictor copies: the state at the start of the step
        real(wp), allocatable :: x_old(:, :)
        real(wp), allocatable :: v_old(:, :)
        real(wp), allocatable :: rho_old(:)
        real(wp), allocatable :: e_old(:)
        ! viscous strain rate (xx, yy, zz, xy, xz, yz) for the strain-rate viscosity
        real(wp), allocatable :: strain(:, :)
        ! wall particles: unit normal into the fluid and distance behind the wall plane
        real(wp), allocatable :: wall_normal(:, :)
        real(wp), allocatable :: wall_distance(:)
        ! identity
        integer(i8), allocatable :: id(:)       !< global id, survives migration and remeshing
        integer, allocatable :: kind(:)         !< KIND_*
        integer, allocatable :: level(:)        !< resolution level, 0 = coarsest
    end type particles_t

contains

    subroutine particles_init(p, capacity, dim)
        type(particles_t), intent(out) :: p
        integer, intent(in) :: capacity, dim
        p%dim = dim
        call allocate_arrays(p, max(capacity, 16))
    end subroutine particles_init

    subroutine allocate_arrays(p, n)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: n
        p%capacity = n
        allocate(p%x(3, n), p%v(3, n), p%rho(n), p%p(n), p%m(n), p%h(n), p%e(n))
        allocate(p%dvdt(3, n), p%drhodt(n), p%dedt(n))
        allocate(p%x_old(3, n), p%v_old(3, n), p%rho_old(n), p%e_old(n))
        allocate(p%strain(6, n), p%wall_normal(3, n), p%wall_distance(n))
        allocate(p%id(n), p%kind(n), p%level(n))
        ! defined values everywhere: unused slots must not trip FP traps when copied
        p%x = 0; p%v = 0; p%rho = 0; p%p = 0; p%m = 0; p%h = 0; p%e = 0
        p%dvdt = 0; p%drhodt = 0; p%dedt = 0
        p%x_old = 0; p%v_old = 0; p%rho_old = 0; p%e_old = 0
        p%strain = 0; p%wall_normal = 0; p%wall_distance = 0
        p%id = 0; p%kind = KIND_FLUID; p%level = 0
    end subroutine allocate_arrays

    subroutine particles_free(p)
        type(particles_t), intent(inout) :: p
        if (allocated(p%x)) then
            deallocate(p%x, p%v, p%rho, p%p, p%m, p%h, p%e, p%dvdt, p%drhodt, p%dedt)
            deallocate(p%x_old, p%v_old, p%rho_old, p%e_old, p%strain)
            deallocate(p%wall_normal, p%wall_distance, p%id, p%kind, p%level)
        end if
        p%n_owned = 0; p%n_ghost = 0; p%n_total = 0; p%capacity = 0
    end subroutine particles_free

    !> Make room for at least n particles, keeping the first n_total (grows by 1.5x).
    subroutine particles_reserve(p, n)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: n
        type(particles_t) :: bigger
        integer :: k
        if (n <= p%capacity) return
        bigger%dim = p%dim
        call allocate_arrays(bigger, max(n, p%capacity + p%capacity / 2, 16))
        do k = 1, p%n_total
            call copy_between(p, k, bigger, k)
        end do
        bigger%n_owned = p%n_owned; bigger%n_ghost = p%n_ghost; bigger%n_total = p%n_total
        call move_alloc(bigger%x, p%x); call move_alloc(bigger%v, p%v)
        call move_alloc(bigger%rho, p%rho); call move_alloc(bigger%p, p%p)
        call move_alloc(bigger%m, p%m); call move_alloc(bigger%h, p%h)
        call move_alloc(bigger%e, p%e); call move_alloc(bigger%dvdt, p%dvdt)
        call move_alloc(bigger%drhodt, p%drhodt); call move_alloc(bigger%dedt, p%dedt)
        call move_alloc(bigger%x_old, p%x_old); call move_alloc(bigger%v_old, p%v_old)
        call move_alloc(bigger%rho_old, p%rho_old); call move_alloc(bigger%e_old, p%e_old)
        call move_alloc(bigger%strain, p%strain)
        call move_alloc(bigger%wall_normal, p%wall_normal)
        call move_alloc(bigger%wall_distance, p%wall_distance)
        call move_alloc(bigger%id, p%id); call move_alloc(bigger%kind, p%kind)
        call move_alloc(bigger%level, p%level)
        p%capacity = bigger%capacity
    end subroutine particles_reserve

    !> Copy particle `from` onto slot `to` within one set.
    subroutine particles_copy(p, from, to)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: from, to
        real(wp) :: buffer(pack_size)
        if (from == to) return
        call particles_pack(p, from, buffer)
        call particles_unpack(p, to, buffer)
    end subroutine particles_copy

    subroutine copy_between(a, i, b, j)
        type(particles_t), intent(in) :: a
        integer, intent(in) :: i, j
        type(particles_t), intent(inout) :: b
        real(wp) :: buffer(pack_size)
        call particles_pack(a, i, buffer)
        call particles_unpack(b, j, buffer)
    end subroutine copy_between

    !> Every field of particle i into a flat real buffer. Integers travel as their bit patterns
    !> (transfer), so ids and kinds arrive exactly.
    pure subroutine particles_pack(p, i, buffer)
        type(particles_t), intent(in) :: p
        integer, intent(in) :: i
        real(wp), intent(out) :: buffer(pack_size)
        buffer(1:3) = p%x(:, i)
        buffer(4:6) = p%v(:, i)
        buffer(7) = p%rho(i)
        buffer(8) = p%p(i)
        buffer(9) = p%m(i)
        buffer(10) = p%h(i)
        buffer(11) = p%e(i)
        buffer(12:14) = p%dvdt(:, i)
        buffer(15) = p%drhodt(i)
        buffer(16) = p%dedt(i)
        buffer(17:19) = p%x_old(:, i)
        buffer(20:22) = p%v_old(:, i)
        buffer(23) = p%rho_old(i)
        buffer(24) = p%e_old(i)
        buffer(25:30) = p%strain(:, i)
        buffer(31:33) = p%wall_normal(:, i)
        buffer(34) = p%wall_distance(i)
        buffer(35) = transfer(p%id(i), 0.0_wp)
        buffer(36) = real(p%kind(i), wp)
        buffer(37) = real(p%level(i), wp)
        buffer(38:40) = 0.0_wp
    end subroutine particles_pack

    pure subroutine particles_unpack(p, i, buffer)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: i
        real(wp), intent(in) :: buffer(pack_size)
        p%x(:, i) = buffer(1:3)
        p%v(:, i) = buffer(4:6)
        p%rho(i) = buffer(7)
        p%p(i) = buffer(8)
        p%m(i) = buffer(9)
        p%h(i) = buffer(10)
        p%e(i) = buffer(11)
        p%dvdt(:, i) = buffer(12:14)
        p%drhodt(i) = buffer(15)
        p%dedt(i) = buffer(16)
        p%x_old(:, i) = buffer(17:19)
        p%v_old(:, i) = buffer(20:22)
        p%rho_old(i) = buffer(23)
        p%e_old(i) = buffer(24)
        p%strain(:, i) = buffer(25:30)
        p%wall_normal(:, i) = buffer(31:33)
        p%wall_distance(i) = buffer(34)
        p%id(i) = transfer(buffer(35), 0_i8)
        p%kind(i) = nint(buffer(36))
        p%level(i) = nint(buffer(37))
    end subroutine particles_unpack

    !> Reorder the owned particles: new slot k takes old particle perm(k). Ghosts are dropped
    !> (they are rebuilt after every reorder).
    subroutine particles_permute_owned(p, perm)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: perm(:)
        real(wp), allocatable :: buffer(:, :)
        integer :: k, n
        n = p%n_owned
        allocate(buffer(pack_size, n))
        do k = 1, n
            call particles_pack(p, perm(k), buffer(:, k))
        end do
        do k = 1, n
            call particles_unpack(p, k, buffer(:, k))
        end do
        p%n_ghost = 0
        p%n_total = n
    end subroutine particles_permute_owned
end module sph_particles
