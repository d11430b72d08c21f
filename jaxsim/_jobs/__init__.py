"""What the command-line jobs (the demo, the report) share: the compilation cache, progress lines, and the demo's scenes."""
