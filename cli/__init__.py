"""The nhstab command line (click). Thin: parse, call one pipeline function, write files."""
