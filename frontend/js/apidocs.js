// Starts Swagger UI 5 on /docs (backend/api/routes/ui.py) with FastAPI's options. A file of its own rather
// than the inline script of FastAPI's page: the Content-Security-Policy runs no inline script.
/* global SwaggerUIBundle */
SwaggerUIBundle({
  url: document.getElementById("swagger-ui").dataset.openapiUrl,
  dom_id: "#swagger-ui",
  layout: "BaseLayout",
  deepLinking: true,
  showExtensions: true,
  showCommonExtensions: true,
  presets: [SwaggerUIBundle.presets.apis, SwaggerUIBundle.SwaggerUIStandalonePreset],
});
