"""Pictures: rendered clips (filmstrips, videos) and plots of stored runs."""
