"""Layout metrics and the HTML report that compares a layout with its example."""
