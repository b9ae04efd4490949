!> Collective loading of the input file: rank 0 reads, the text is broadcast, every rank parses
!> and validates the same text, so a bad input stops all ranks with the same single message.
!> What the text alone does not decide (whether &output output_dir can be made) rank 0 asks
!> the file system, and every rank takes its verdict.
module sph_input
    use sph_config, only: config_t, config_parse, config_read_file
    use sph_mpi_env, only: mpi_env_t, broadcast_text, agreed_status, rank0_flag
    implicit none
    private
    public :: load_config

contains

    !> Read the namelist file on rank 0, share its text, parse and check every group on all
    !> ranks; stat /= 0 and one message per bad key otherwise.
    subroutine load_config(env, filename, cfg, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: filename
        type(config_t), intent(out) :: cfg
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        character(len=:), allocatable :: text, read_error

        stat = 0
        if (env%rank == 0) then
            call config_read_file(filename, text, stat, read_error)
            if (stat /= 0) text = read_error
        end if
        ! the read's status on its own (a marker in the text would be a file's first byte)
        stat = agreed_status(env, merge(1, 0, stat /= 0))
        call broadcast_text(env, text)
        if (stat /= 0) then
            errmsg = text
            return
        end if
        ! only rank 0 asks the file system: ranks that saw it differently (another working
        ! folder, a network file system's cache) went on apart, one into a collective stop
        ! and the others into the set-up's collectives (fz51: a hang)
        call config_parse(cfg, text, filename, stat, errmsg, check_paths=env%rank == 0)
        ! (the other ranks made the same checks but that one: rank 0's message is the whole)
        stat = merge(1, 0, rank0_flag(env, stat /= 0))
        if (stat /= 0) call broadcast_text(env, errmsg)
    end subroutine load_config
end module sph_input
