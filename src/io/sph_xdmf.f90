!> XDMF (version 3) time series beside the snapshots, so ParaView and VisIt open a whole run
!> at once: one Polyvertex grid per snapshot, pointing into its HDF5 datasets. Written by
!> rank 0 alone, after each snapshot file is complete, whole or not at all (a temporary name,
!> renamed once every byte is written).
module sph_xdmf
    use sph_kinds, only: wp, i8
    use sph_filesystem, only: write_text_file_whole, text_buffer_t
    use sph_particles, only: field_list, field_info_t, FIELD_SNAPSHOT, FIELD_REAL, FIELD_INT8
    implicit none
    private
    public :: xdmf_index_entry, write_xdmf


contains

    !> One line of the run's snapshot index: time, step, rows, file name (no folder).
    function xdmf_index_entry(time, step, rows, file_name) result(line)
        real(wp), intent(in) :: time
        integer(i8), intent(in) :: step, rows
        character(len=*), intent(in) :: file_name
        character(len=:), allocatable :: line
        character(len=96) :: numbers
        write(numbers, '(es24.16,1x,i0,1x,i0)') time, step, rows
        line = trim(adjustl(numbers)) // ' ' // file_name // new_line('a')
    end function xdmf_index_entry

    !> Write `path` from the index text (one xdmf_index_entry per snapshot). stat /= 0 and
    !> errmsg (the system's reason) when the file cannot be written; `path` is then as it was.
    subroutine write_xdmf(path, index_text, stat, errmsg)
        character(len=*), intent(in) :: path, index_text
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        type(text_buffer_t) :: doc
        integer :: start, k, ios, f
        real(wp) :: time
        integer(i8) :: step, rows
        character(len=512) :: file_name
        character(len=32) :: n_text, width_text, number
        type(field_info_t), allocatable :: fields(:)
        character(len=16) :: attribute_type

        ! every snapshot field of the particle table but the positions (the geometry)
        fields = field_list()
        call line('<?xml version="1.0" ?>')
        call line('<Xdmf Version="3.0">')
        call line(' <Domain>')
        call line('  <Grid Name="particles" GridType="Collection" ' // &
            'CollectionType="Temporal">')
        start = 1
        do k = 1, len(index_text)
            if (index_text(k:k) /= new_line('a')) cycle
            read(index_text(start:k - 1), *, iostat=ios) time, step, rows, file_name
            start = k + 1
            if (ios /= 0) cycle
            write(n_text, '(i0)') rows
            write(number, '(i0)') step
            call line('   <Grid Name="step_' // trim(number) // '" GridType="Uniform">')
            write(number, '(es24.16)') time
            call line('    <Time Value="' // number(1:24) // '"/>')
            call line('    <Topology TopologyType="Polyvertex" NumberOfElements="' // &
                trim(n_text) // '"/>')
            call line('    <Geometry GeometryType="XYZ">')
            call data_item('position', 'Float', 8, trim(n_text) // ' 3')
            call line('    </Geometry>')
            call line('    <Attribute Name="velocity" AttributeType="Vector" ' // &
                'Center="Node">')
            call data_item('velocity', 'Float', 8, trim(n_text) // ' 3')
            call line('    </Attribute>')
            do f = 1, size(fields)
                if (iand(fields(f)%flags, FIELD_SNAPSHOT) == 0) cycle
                if (fields(f)%name == 'position' .or. fields(f)%name == 'velocity') cycle
                select case (fields(f)%width)
                case (1); attribute_type = 'Scalar'
                case (3); attribute_type = 'Vector'
                case (6); attribute_type = 'Tensor6'
                case default; attribute_type = 'Matrix'
                end select
                call line('    <Attribute Name="' // trim(fields(f)%name) // &
                    '" AttributeType="' // trim(attribute_type) // '" Center="Node">')
                width_text = n_text
                if (fields(f)%width > 1) write(width_text, '(a,1x,i0)') trim(n_text), &
                    fields(f)%width
                select case (fields(f)%storage)
                case (FIELD_REAL)
                    call data_item(trim(fields(f)%name), 'Float', 8, trim(width_text))
                case (FIELD_INT8)
                    call data_item(trim(fields(f)%name), 'Int', 8, trim(width_text))
                case default
                    call data_item(trim(fields(f)%name), 'Int', 4, trim(width_text))
                end select
                call line('    </Attribute>')
            end do
            ! the writing rank of each row (sph_snapshot)
            call line('    <Attribute Name="rank" AttributeType="Scalar" Center="Node">')
            call data_item('rank', 'Int', 4, trim(n_text))
            call line('    </Attribute>')
            call line('   </Grid>')
        end do
        call line('  </Grid>')
        call line(' </Domain>')
        call line('</Xdmf>')
        call write_text_file_whole(path, doc%text(1:doc%used), stat, errmsg)
    contains
        subroutine line(text)
            character(len=*), intent(in) :: text
            call doc%put(text // new_line('a'))
        end subroutine line

        subroutine data_item(dataset, number_type, precision, dimensions)
            character(len=*), intent(in) :: dataset, number_type, dimensions
            integer, intent(in) :: precision
            character(len=8) :: bytes
            write(bytes, '(i0)') precision
            call line('     <DataItem Dimensions="' // dimensions // '" NumberType="' // &
                number_type // '" Precision="' // trim(bytes) // '" Format="HDF">' // &
                trim(file_name) // ':/particles/' // dataset // '</DataItem>')
        end subroutine data_item
    end subroutine write_xdmf
end module sph_xdmf
