!> Small configurations shared by the flow tests, built from namelist text exactly as a user
!> would write them.
module test_sph_cases
    use, intrinsic :: iso_fortran_env, only: error_unit
    use sph_kinds, only: wp
    use sph_config, only: config_t, config_parse
    use sph_domain, only: domain_t, domain_set_tree
    implicit none
    private
    public :: config_from_text, channel_text, periodic_box_text, closed_box_text
    public :: single_rank_domain

    character(len=*), parameter :: nl = new_line('a')

contains

    !> Parse and validate; a failure here is a broken test, so it stops loudly.
    !> With `lid`, the upper face of the second axis (yhi) slides along x at that speed, set
    !> after the input checks: unit tests of the particle mechanics use lid corners with any
    !> model, which the input refuses for runs (sph_physics_input, check_moving_corners).
    function config_from_text(text, lid) result(cfg)
        character(len=*), intent(in) :: text
        real(wp), intent(in), optional :: lid
        type(config_t) :: cfg
        integer :: stat
        character(len=:), allocatable :: msg
        call config_parse(cfg, text, 'test', stat, msg)
        if (stat /= 0) then
            write(error_unit, '(a)') 'test configuration invalid: ' // msg
            error stop 1
        end if
        if (present(lid)) cfg%domain%wall_velocity(:, 4) = [lid, 0.0_wp, 0.0_wp]
    end function config_from_text

    !> Morris' channel (L = 1e-3 m), Poiseuille or Couette, at dx = L / n_across; L/2 long,
    !> and at least 6 dx (two kernel supports of 2.6 dx: the input check refuses less).
    function channel_text(kind, n_across, t_end) result(text)
        character(len=*), intent(in) :: kind
        integer, intent(in) :: n_across
        real(wp), intent(in) :: t_end
        character(len=:), allocatable :: text
        character(len=64) :: dx_text, t_text, length_text
        write(dx_text, '(es24.16)') 1.0e-3_wp / n_across
        length_text = '0.5e-3'
        if (n_across < 12) write(length_text, '(es24.16)') 1.0e-3_wp / n_across * 6.0_wp
        write(t_text, '(es24.16)') t_end
        text = "&run case_name='" // kind // "', t_end=" // trim(t_text) // ", analytic='" // &
            kind // "' /" // nl // &
            "&domain dimension=2, box_hi=" // trim(length_text) // ", 1.0e-3, dx=" // &
            trim(dx_text) // &
            ", boundary='periodic','periodic','wall','wall'"
        if (kind == 'couette') text = text // ", wall_velocity(1,4)=2.5e-5"
        text = text // " /" // nl // "&fluid rho0=1000.0, nu=1.0e-6"
        if (kind == 'poiseuille') text = text // ", body_force=2.0e-4, 0.0"
        text = text // " /" // nl
    end function channel_text

    !> A fully periodic box of n x n (x n) particles with a given sound speed (and EOS).
    function periodic_box_text(dim, n, eos) result(text)
        integer, intent(in) :: dim, n
        character(len=*), intent(in), optional :: eos
        character(len=:), allocatable :: text
        character(len=64) :: dim_text, dx_text
        write(dim_text, '(i0)') dim
        write(dx_text, '(es24.16)') 1.0e-3_wp / n
        text = "&run case_name='box' /" // nl // &
            "&domain dimension=" // trim(dim_text) // ", box_hi=1.0e-3, 1.0e-3, 1.0e-3, dx=" // &
            trim(dx_text) // " /" // nl // &
            "&fluid rho0=1000.0, nu=1.0e-6, sound_speed=1.0e-2"
        if (present(eos)) text = text // ", eos='" // eos // "'"
        text = text // " /" // nl
    end function periodic_box_text

    !> A box of n x n (x n) particles closed by walls on every face, sound speed 1e-2 m/s,
    !> with an optional &numerics body (e.g. "wall_model='mirror'"), equation of state and
    !> x velocity of the upper y wall (a lid).
    function closed_box_text(dim, n, numerics, eos) result(text)
        integer, intent(in) :: dim, n
        character(len=*), intent(in), optional :: numerics, eos
        character(len=:), allocatable :: text
        character(len=64) :: dim_text, dx_text
        integer :: f
        write(dim_text, '(i0)') dim
        write(dx_text, '(es24.16)') 1.0e-3_wp / n
        text = "&run case_name='closed' /" // nl // &
            "&domain dimension=" // trim(dim_text) // ", box_hi=1.0e-3, 1.0e-3, 1.0e-3, dx=" // &
            trim(dx_text) // ", boundary="
        do f = 1, 2 * dim
            text = text // "'wall'"
            if (f < 2 * dim) text = text // ","
        end do
        text = text // " /" // nl // "&fluid rho0=1000.0, nu=1.0e-6, sound_speed=1.0e-2"
        if (present(eos)) text = text // ", eos='" // eos // "'"
        text = text // " /" // nl
        if (present(numerics)) text = text // "&numerics " // numerics // " /" // nl
    end function closed_box_text

    !> The decomposition of a single rank (one leaf owning everything), made without MPI, so
    !> serial tests can call create_lattice_particles.
    function single_rank_domain(cfg) result(domain)
        type(config_t), intent(in) :: cfg
        type(domain_t) :: domain
        integer :: axis
        domain%dim = cfg%domain%dimension
        domain%nranks = 1
        domain%rank = 0
        domain%lo = cfg%domain%box_lo
        domain%hi = cfg%domain%box_hi
        domain%length = cfg%domain%box_hi - cfg%domain%box_lo
        domain%periodic = .false.
        do axis = 1, cfg%domain%dimension
            domain%periodic(axis) = cfg%domain%is_periodic(axis)
        end do
        call domain_set_tree(domain, [0], [0], [0], [0], [0.0_wp])
    end function single_rank_domain
end module test_sph_cases
