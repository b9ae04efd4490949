!> Collective loading of the input file: rank 0 reads, the text is broadcast, every rank parses
!> and validates the same text, so a bad input stops all ranks with the same single message.
module sph_input
    use sph_config, only: config_t, config_parse, config_read_file
    use sph_mpi_env, only: mpi_env_t, broadcast_text
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

        if (env%rank == 0) then
            call config_read_file(filename, text, stat, read_error)
            if (stat /= 0) text = achar(0) // read_error   ! a NUL marks a read failure
        end if
        call broadcast_text(env, text)
        if (len(text) > 0) then
            if (text(1:1) == achar(0)) then
                stat = 1
                errmsg = text(2:)
                return
            end if
        end if
        call config_parse(cfg, text, filename, stat, errmsg)
    end subroutine load_config
end module sph_input
