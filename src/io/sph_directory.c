/* Directory listing for Fortran (which has none): the names in a directory, separated by
 * new lines, for finding the newest complete checkpoint when a run continues from a folder. */
#include <dirent.h>
#include <string.h>

/* Writes the entry names of `path` into `buffer` (at most `capacity` bytes, '\n' after each
 * name). Returns the number of bytes written, or -1 if the directory cannot be read, or -2 if
 * the buffer is too small. */
int sph_list_directory(const char *path, char *buffer, int capacity)
{
    DIR *dir = opendir(path);
    struct dirent *entry;
    int used = 0;
    if (dir == NULL)
        return -1;
    while ((entry = readdir(dir)) != NULL) {
        int length = (int)strlen(entry->d_name);
        if (used + length + 1 > capacity) {
            closedir(dir);
            return -2;
        }
        memcpy(buffer + used, entry->d_name, (size_t)length);
        used += length;
        buffer[used++] = '\n';
    }
    closedir(dir);
    return used;
}
