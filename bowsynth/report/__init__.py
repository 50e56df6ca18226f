"""Listening reports: self-contained HTML pages that put the sound beside the picture.

compare_page: `bowsynth compare X --report R.html`; models_page: `bowsynth models --report M.html`; html: the page
pieces (embedded audio, inline SVG, tables); listen: the listener measures the pages draw."""
